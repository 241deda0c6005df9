"""Pose Fisher information of a set of landmarks seen by a pinhole camera, and the grid search over views.

For a landmark at camera coordinates p = (x, y, z) the pixel Jacobian is
J = ∂(u, v)/∂p · [−[p]ₓ | I] with respect to a 6-DoF perturbation (δθ, δt) of the camera (p' = p + δθ×p + δt),
∂(u, v)/∂p = [[fx/z, 0, −fx·x/z²], [0, fy/z, −fy·y/z²]]. With isotropic pixel noise σ the information is
F = Σ JᵀJ / σ² over the landmarks in view. The baseline scores a view by log det(F + εI) (ε keeps a
view with fewer than three landmarks finite and last) and takes the argmax over a grid of views, as
FIF's per-position orientation search does.
"""

from __future__ import annotations

import numpy as np

from pivotd.localization.camera import CameraModel, image_coordinates, to_camera

EPSILON = 1e-9  # [px⁻² units] regulariser of the log-determinant


def pose_information(model: CameraModel, R_wc: np.ndarray, centre: np.ndarray, points: np.ndarray,
                     sigma: float = 1.0) -> np.ndarray:
    """Fisher information (O, 6, 6) of the camera pose for O orientations ``R_wc`` (O, 3, 3).

    ``points`` (N, 3): landmarks already known to be in line of sight of ``centre`` (3,); only those
    inside each view's image and depth range contribute. Units: rotation in rad, translation in m.
    The Jacobians are formed only for the (view, landmark) pairs in the image, and the 21 distinct
    entries of each JᵀJ summed per view.
    """
    R = np.asarray(R_wc, float).reshape(-1, 3, 3)
    views = R.shape[0]
    pc = to_camera(R, centre, points)  # (O, N, 3)
    _, _, inside = image_coordinates(model, pc)
    view, lm = np.nonzero(inside)  # sorted by view
    info = np.zeros((views, 6, 6))
    if view.size == 0:
        return info
    p = pc[view, lm]  # (K, 3)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    iz = 1.0 / z
    zeros = np.zeros_like(iz)
    # Rows of ∂(u,v)/∂p: a = fx·(1/z, 0, −x/z²), b = fy·(0, 1/z, −y/z²); J = [a·(−[p]ₓ), a] etc.
    a = model.fx * np.column_stack([iz, zeros, -x * iz * iz])
    b = model.fy * np.column_stack([zeros, iz, -y * iz * iz])
    # r·(−[p]ₓ) = (p × r)ᵀ for a row r of ∂(u,v)/∂p
    ja = np.concatenate([np.cross(p, a), a], axis=1)  # (K, 6)
    jb = np.concatenate([np.cross(p, b), b], axis=1)
    iu, ju = np.triu_indices(6)
    terms = ja[:, iu] * ja[:, ju] + jb[:, iu] * jb[:, ju]  # (K, 21)
    starts = np.flatnonzero(np.r_[True, view[1:] != view[:-1]])
    sums = np.add.reduceat(terms, starts, axis=0)  # (views with landmarks, 21)
    rows = view[starts]
    info[rows[:, None], iu[None, :], ju[None, :]] = sums
    info[rows[:, None], ju[None, :], iu[None, :]] = sums
    return info / (sigma * sigma)


def information_score(info: np.ndarray) -> np.ndarray:
    """log det(F + εI) for information matrices (..., 6, 6)."""
    _, logdet = np.linalg.slogdet(info + EPSILON * np.eye(6))
    return logdet


def best_view(model: CameraModel, R_candidates: np.ndarray, centre: np.ndarray, points: np.ndarray,
              chunk: int = 64) -> tuple[int, np.ndarray]:
    """Index of the candidate orientation (O, 3, 3) with the largest information score, and all scores (O,)."""
    R = np.asarray(R_candidates, float).reshape(-1, 3, 3)
    scores = np.empty(R.shape[0])
    for lo in range(0, R.shape[0], chunk):
        scores[lo:lo + chunk] = information_score(pose_information(model, R[lo:lo + chunk], centre, points))
    return int(np.argmax(scores)), scores
