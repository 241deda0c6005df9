"""The COLMAP text model shipped in tests/data/colmap_small: three cameras 1 m apart at 1 m height looking along +y
at a wall of 12 landmarks at y = 5 m (one landmark not seen from the first camera), read as pivotd reads a map."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from pivotd.maps.formats import load_landmarks

MODEL = Path(__file__).parent / "data" / "colmap_small"
CENTRES = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [2.0, 0.0, 1.0]])  # the cameras the model was made from
WALL = np.array([[x, 5.0, z] for x in (-1.0, 0.5, 2.0, 3.0) for z in (0.5, 1.5, 2.5)])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_points_and_observation_directions_of_the_model():
    cloud = load_landmarks(MODEL)
    assert len(cloud) == 12
    np.testing.assert_allclose(cloud.points, WALL, atol=1e-6)
    np.testing.assert_array_equal(cloud.weights, np.ones(12, np.float32))
    assert cloud.directions is not None
    expected = np.empty_like(WALL)
    for i, p in enumerate(WALL):
        seen_by = CENTRES[1:] if i == 11 else CENTRES  # the last landmark is not in the first image's track
        expected[i] = _unit(_unit(seen_by - p).mean(axis=0))
    np.testing.assert_allclose(cloud.directions, expected, atol=1e-6)
    # every direction points from the wall back towards the cameras (−y), none is unknown
    assert np.all(cloud.directions[:, 1] < -0.8)


def test_check_accepts_a_config_on_the_model_and_its_view_filter(tmp_path):
    config = tmp_path / "colmap.yaml"
    config.write_text(f"map:\n  file: {MODEL}\n  filters: {{max_view_angle_deg: 60}}\n")
    result = subprocess.run([sys.executable, "-m", "pivotd.cli", "check", "--config", str(config)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "(12 landmarks" in result.stdout
