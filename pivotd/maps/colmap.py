"""COLMAP sparse models: ``points3D.bin|txt`` and, when beside them, ``images.bin|txt``.

Layouts (COLMAP's documented output format):

* ``points3D.bin``: ``u64 count``, then per point ``u64 id, f64 x, y, z, u8 r, g, b, f64 error,
  u64 track_length`` (51 bytes) and ``track_length`` × ``(i32 image_id, i32 point2D_idx)``.
* ``points3D.txt``: ``POINT3D_ID X Y Z R G B ERROR (IMAGE_ID POINT2D_IDX)*`` per line.
* ``images.bin``: ``u64 count``, then per image ``i32 id, f64 qw, qx, qy, qz, tx, ty, tz, i32 camera_id``,
  a NUL-terminated name, ``u64 n`` and ``n`` × ``(f64 x, f64 y, i64 point3D_id)``.
* ``images.txt``: two lines per image, ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` and the
  (possibly empty) ``(X Y POINT3D_ID)*`` line.

The pose (q, t) maps world to camera, so a camera centre is ``-R(q)ᵀ t``. A landmark's observation
direction is the normalised mean of the unit vectors from the landmark to the centres of the
images in its track; observations of images missing from the images file are ignored, and a
landmark left without any gets the zero vector (treated as "unknown" by the view filter).

The binary reader walks the variable-length records once to find their offsets (one cheap
step per point) and extracts coordinates and tracks with vectorised gathers.
"""

from __future__ import annotations

import array
import logging
import math
import os
import struct
from collections.abc import Callable, Iterator
from contextlib import closing
from pathlib import Path

import numpy as np

from pivotd.errors import InputError
from pivotd.geometry import MAX_COORDINATE, quat_to_matrix, safe_unit_quats
from pivotd.maps.formats import LandmarkCloud, make_cloud
from pivotd.progress import Progress

log = logging.getLogger(__name__)

_POINT_HEAD = 51  # id, xyz, rgb, error, track_length
_TRACK_ELEM = 8
_BLOCK = 1 << 13  # landmarks per vectorised block of direction averaging (temporaries ~40 B per observation)
_HEAD_BLOCK = 1 << 14  # records per block when reading heads (a multiple of 8; ~1 MB of file stays cached)
_TRACK_BLOCK = 1 << 12  # records per block when reading tracks (a multiple of 4)
_IMAGE_HEAD = struct.Struct("<idddddddi")  # 64 bytes
_I32_MIN, _I32_MAX = -(1 << 31), (1 << 31) - 1
_PROGRESS_BLOCK = 1 << 16  # point records between progress updates of the binary reader
_PROGRESS_LINES = 1 << 14  # lines between progress updates of the text readers


def resolve_model(path: Path) -> tuple[Path, Path | None]:
    """(points3D file, images file or None) for a model directory or a points3D file."""
    if path.is_dir():
        for ext in (".bin", ".txt"):
            if (path / f"points3D{ext}").exists():
                points = path / f"points3D{ext}"
                break
        else:
            raise InputError(f"{path}: directory holds no COLMAP points3D.bin or points3D.txt")
    else:
        points = path
    if points.suffix not in (".bin", ".txt"):
        raise InputError(f"{points}: COLMAP points3D file must end in .bin or .txt")
    images = None
    for ext in (points.suffix, ".bin" if points.suffix == ".txt" else ".txt"):
        if (points.parent / f"images{ext}").exists():
            images = points.parent / f"images{ext}"
            break
    return points, images


def load_colmap(path: Path) -> LandmarkCloud:
    """Landmarks (and mean observation directions when images are present) of a COLMAP model."""
    points_file, images_file = resolve_model(path)
    if points_file.suffix == ".bin":
        xyz, lengths, track_img = read_points3d_bin(points_file, with_tracks=images_file is not None)
    else:
        xyz, lengths, track_img = read_points3d_txt(points_file)
    cloud = make_cloud(points_file, xyz, None, None, row_name="point")  # validated before any arithmetic
    if images_file is None:
        return cloud
    ids, centers = read_images_bin(images_file) if images_file.suffix == ".bin" else read_images_txt(images_file)
    directions = observation_directions(cloud.points, lengths, track_img, ids, centers)
    return LandmarkCloud(cloud.points, cloud.weights, directions)


# --- points3D ---------------------------------------------------------------------------------


def _record_offsets(buf: bytes, path: Path, count: int, progress: Progress) -> np.ndarray:
    """Byte offsets (count,) int64 of the variable-length point records (one cheap step per record)."""
    read_u64 = struct.Struct("<Q").unpack_from
    offsets = array.array("q")  # raw int64: lighter and faster to append than a list of ints
    append = offsets.append
    off = 8
    try:
        for start in range(0, count, _PROGRESS_BLOCK):
            for _ in range(min(_PROGRESS_BLOCK, count - start)):
                append(off)
                off += _POINT_HEAD + _TRACK_ELEM * read_u64(buf, off + 43)[0]
            progress.update(off)
    except struct.error:
        k = len(offsets) - 1
        raise InputError(f"{path}: truncated at byte {offsets[-1]} (point record {k} of {count})") from None
    except OverflowError:
        k = len(offsets) - 1
        raise InputError(f"{path}: corrupt track length in point record {k} at byte {offsets[-1]}") from None
    if off > len(buf):
        raise InputError(f"{path}: truncated at byte {len(buf)} (track of point record {count - 1} ends at {off})")
    if off != len(buf):
        raise InputError(f"{path}: {len(buf) - off} unexpected trailing bytes at byte {off}")
    return np.frombuffer(offsets, dtype=np.int64) if count else np.zeros(0, np.int64)


def _record_heads(buf: bytes, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """xyz (N, 3) float64 and track lengths (N,) int64 from the record heads at ``offsets`` (N,).

    Records are 51 + 8·n bytes long, so record k starts at 3k (mod 8): records k ≡ r (mod 8) share one
    alignment and are read through one aligned view with strided slices (no per-record work). Blocks of
    records in file order keep the touched part of the file in cache for both fields.
    """
    n = offsets.shape[0]
    xyz = np.empty((n, 3), dtype=np.float64)
    lengths = np.empty(n, dtype=np.int64)
    f8 = [np.frombuffer(buf, dtype="<f8", offset=s, count=(len(buf) - s) // 8) for s in range(8)]
    u8 = [np.frombuffer(buf, dtype="<u8", offset=s, count=(len(buf) - s) // 8) for s in range(8)]
    lane = np.arange(3)
    for a in range(0, n, _HEAD_BLOCK):
        b = min(n, a + _HEAD_BLOCK)
        for r in range(8):
            offs = offsets[a + r:b:8]
            if offs.size == 0:
                continue
            s = int((offs[0] + 8) % 8)
            xyz[a + r:b:8] = f8[s][((offs + 8 - s) >> 3)[:, None] + lane]
            s = int((offs[0] + 43) % 8)
            lengths[a + r:b:8] = u8[s][(offs + 43 - s) >> 3]
    return xyz, lengths


def _counted_file(path: Path, what: str) -> tuple[bytes, int]:
    """Bytes of a COLMAP binary file and its leading uint64 record count; errors name the file."""
    try:
        buf = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    if len(buf) < 8:
        raise InputError(f"{path}: truncated at byte {len(buf)} (no {what} count)")
    return buf, struct.unpack_from("<Q", buf, 0)[0]


def read_points3d_bin(path: Path, with_tracks: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """xyz (N, 3) float64, track lengths (N,) int64 and the image id of every observation (T,) int32
    (grouped by point, in point order; None unless ``with_tracks``) of a ``points3D.bin``."""
    buf, count = _counted_file(path, "point")
    if count > (len(buf) - 8) // _POINT_HEAD:
        raise InputError(
            f"{path}: header claims {count} points but the file holds at most {(len(buf) - 8) // _POINT_HEAD} "
            "(not a points3D.bin, or truncated)"
        )
    with Progress(f"reading {path.name}", len(buf), "B") as progress:
        offsets = _record_offsets(buf, path, count, progress)
    xyz, lengths = _record_heads(buf, offsets)
    if not with_tracks:
        return xyz, lengths, None
    total = int(lengths.sum())
    first = np.cumsum(lengths) - lengths  # position of each point's first observation
    track_img = np.empty(total, dtype=np.int32)
    # Observation j of record k sits at offset_k + 51 + 8j ≡ 3k + 3 (mod 4): one aligned int32 view per k mod 4.
    # Blocks of points (a multiple of 4) keep the temporaries small.
    for a in range(0, count, _TRACK_BLOCK):
        b = min(count, a + _TRACK_BLOCK)
        for r in range(4):
            lk = lengths[a + r:b:4]
            nk = int(lk.sum())
            if nk == 0:
                continue
            j = np.arange(nk, dtype=np.int64)
            j -= np.repeat(np.cumsum(lk) - lk, lk)
            pos = np.repeat(first[a + r:b:4], lk) + j
            off = np.repeat(offsets[a + r:b:4] + _POINT_HEAD, lk) + _TRACK_ELEM * j
            shift = int(off[0] % 4)
            view = np.frombuffer(buf, dtype="<i4", offset=shift, count=(len(buf) - shift) // 4)
            track_img[pos] = view[(off - shift) >> 2]
    return xyz, lengths, track_img


def read_points3d_txt(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Same as :func:`read_points3d_bin` for ``points3D.txt``; errors name the line.

    Values go straight into typed arrays (8 bytes per number), so memory stays a small multiple of the
    file size whatever its content.
    """
    with closing(_text_lines(path)) as numbered:  # closed (progress line ended) before an error propagates
        return _points3d_rows(path, numbered)


def _points3d_rows(path: Path, numbered: Iterator[tuple[int, str]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    xyz = array.array("d")
    lengths = array.array("q")
    track_img = array.array("i")
    for lineno, line in numbered:
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = line.split()
        if len(fields) < 8 or (len(fields) - 8) % 2:
            raise InputError(
                f"{path}:{lineno}: expected POINT3D_ID X Y Z R G B ERROR and (IMAGE_ID POINT2D_IDX) pairs, "
                f"got {len(fields)} fields"
            )
        try:
            x, y, z = float(fields[1]), float(fields[2]), float(fields[3])
            int(fields[0])
            track = list(map(int, fields[8::2]))
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a number in {line.strip()[:80]!r}") from None
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise InputError(f"{path}:{lineno}: coordinate is not finite (NaN or inf)")
        try:
            track_img.extend(track)
        except OverflowError:
            bad = next(v for v in track if not _I32_MIN <= v <= _I32_MAX)
            raise InputError(f"{path}:{lineno}: image id {bad} is out of range (COLMAP ids are 32-bit)") from None
        lengths.append(len(track))
        xyz.extend((x, y, z))
    return (np.frombuffer(xyz, dtype=np.float64).reshape(-1, 3), np.frombuffer(lengths, dtype=np.int64),
            np.frombuffer(track_img, dtype=np.int32))


# --- images -----------------------------------------------------------------------------------


def camera_centers(qwxyz: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Camera centres (K, 3) = -R(q)ᵀ t from world-to-camera quaternions (K, 4) (w, x, y, z) and t (K, 3)."""
    q, _ = safe_unit_quats(np.asarray(qwxyz, dtype=float)[:, [1, 2, 3, 0]])
    return -np.einsum("kji,kj->ki", quat_to_matrix(q), np.asarray(t, dtype=float))


def read_images_bin(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Image ids (K,) and camera centres (K, 3) from ``images.bin``; errors name the byte offset."""
    buf, count = _counted_file(path, "image")
    if count > (len(buf) - 8) // (_IMAGE_HEAD.size + 9):
        raise InputError(f"{path}: header claims {count} images, more than the file can hold (not an images.bin?)")
    ids = np.empty(count, dtype=np.int64)
    poses = np.empty((count, 7))
    off = 8
    for k in range(count):
        if off + _IMAGE_HEAD.size > len(buf):
            raise InputError(f"{path}: truncated at byte {off} (image record {k} of {count})")
        rec = _IMAGE_HEAD.unpack_from(buf, off)
        ids[k] = rec[0]
        poses[k] = rec[1:8]
        off += _IMAGE_HEAD.size
        end = buf.find(b"\0", off)
        if end < 0:
            raise InputError(f"{path}: truncated at byte {off} (image {rec[0]} name has no terminator)")
        off = end + 1
        if off + 8 > len(buf):
            raise InputError(f"{path}: truncated at byte {off} (image {rec[0]} keypoint count)")
        n = struct.unpack_from("<Q", buf, off)[0]
        off += 8 + 24 * n
        if off > len(buf):
            raise InputError(f"{path}: truncated at byte {len(buf)} (keypoints of image {rec[0]})")
    if off != len(buf):
        raise InputError(f"{path}: {len(buf) - off} unexpected trailing bytes at byte {off}")
    _check_poses(path, ids, poses, "image")
    return ids, camera_centers(poses[:, :4], poses[:, 4:])


def read_images_txt(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Image ids (K,) and camera centres (K, 3) from ``images.txt``; errors name the line."""
    with closing(_text_lines(path)) as numbered:  # closed (progress line ended) before an error propagates
        return _images_rows(path, numbered)


def _images_rows(path: Path, numbered: Iterator[tuple[int, str]]) -> tuple[np.ndarray, np.ndarray]:
    ids = array.array("i")
    poses = array.array("d")
    # Each image takes two lines; the keypoint line (possibly empty) follows its header line.
    # Blank lines between images are skipped.
    keypoints_next = False
    for lineno, line in numbered:
        if line.lstrip().startswith("#"):
            continue
        if keypoints_next:
            keypoints_next = False
            continue
        if not line.strip():
            continue
        fields = line.split()
        if len(fields) < 10:
            raise InputError(
                f"{path}:{lineno}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got {len(fields)} fields"
            )
        try:
            image_id = int(fields[0])
            pose = [float(f) for f in fields[1:8]]
            int(fields[8])
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a number in {line.strip()[:80]!r}") from None
        if not _I32_MIN <= image_id <= _I32_MAX:
            raise InputError(f"{path}:{lineno}: image id {image_id} is out of range (COLMAP ids are 32-bit)")
        ids.append(image_id)
        poses.extend(pose)
        keypoints_next = True
    arr = np.frombuffer(poses, dtype=np.float64).reshape(-1, 7)
    id_arr = np.frombuffer(ids, dtype=np.int32).astype(np.int64)
    _check_poses(path, id_arr, arr, "image")
    return id_arr, camera_centers(arr[:, :4], arr[:, 4:])


def _check_poses(path: Path, ids: np.ndarray, poses: np.ndarray, what: str) -> None:
    _, usable = safe_unit_quats(poses[:, :4])
    bad = ~np.isfinite(poses).all(axis=1) | ~usable
    if bad.any():
        raise InputError(f"{path}: {what} {int(ids[np.argmax(bad)])} has a non-finite pose or zero quaternion")
    far = np.abs(poses[:, 4:]).max(axis=1, initial=0.0) > MAX_COORDINATE
    if far.any():
        raise InputError(f"{path}: {what} {int(ids[np.argmax(far)])} has a translation beyond ±{MAX_COORDINATE:g} m")
    if ids.size and ids.min() < 0:
        raise InputError(f"{path}: {what} id {int(ids.min())} is negative")


def _text_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(1-based line number, line) of a text file, read lazily; errors name the file."""
    try:
        with open(path) as fh, Progress(f"reading {path.name}", os.fstat(fh.fileno()).st_size, "B") as progress:
            chars = 0
            for lineno, line in enumerate(fh, start=1):
                chars += len(line)  # characters: bytes for the ASCII of COLMAP text files
                if not lineno % _PROGRESS_LINES:
                    progress.update(chars)
                yield lineno, line
            progress.update(chars)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None


# --- directions -------------------------------------------------------------------------------


def observation_directions(
    xyz: np.ndarray, lengths: np.ndarray, track_img: np.ndarray, image_ids: np.ndarray, centers: np.ndarray
) -> np.ndarray:
    """Unit mean landmark→camera directions (N, 3) float32; zero rows for landmarks without known images.

    xyz: (N, 3) landmarks; lengths: (N,) observations per landmark; track_img: (T,) image id of each
    observation, grouped by landmark in order; image_ids: (K,); centers: (K, 3) camera centres.
    Computed in float32, in blocks of landmarks to keep temporaries small.
    """
    n = xyz.shape[0]
    out = np.zeros((n, 3), dtype=np.float32)
    if track_img.size == 0 or image_ids.size == 0:
        return out
    to_row = _image_rows(image_ids)
    centers32 = np.concatenate([centers, np.zeros((1, 3))]).astype(np.float32)  # row K: unknown image
    first = np.concatenate([[0], np.cumsum(lengths)])
    missing = 0
    progress = Progress("observation directions", n, "points")  # no exits below but the loop's end
    for a in range(0, n, _BLOCK):
        b = min(n, a + _BLOCK)
        progress.update(b)
        lk = lengths[a:b]
        if first[b] == first[a]:
            continue
        img = track_img[first[a]:first[b]]
        cam = to_row(img)
        unknown = cam < 0
        cam[unknown] = image_ids.size
        missing += int(unknown.sum())
        v = np.take(centers32, cam, axis=0)
        v -= np.repeat(xyz[a:b].astype(np.float32), lk, axis=0)
        norm = np.sqrt(np.einsum("ij,ij->i", v, v))
        norm[unknown] = np.inf  # contributes a zero vector
        v /= np.maximum(norm, np.float32(1e-12))[:, None]
        seen = np.flatnonzero(lk)
        mean = np.add.reduceat(v, (first[a:b] - first[a])[seen], axis=0)
        mnorm = np.sqrt(np.einsum("ij,ij->i", mean, mean))
        good = mnorm > 1e-6
        out[a + seen[good]] = mean[good] / mnorm[good, None]
    progress.close()
    if missing:
        log.info("%d observations refer to images missing from the model; ignored", missing)
    return out


def _image_rows(image_ids: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Function mapping image ids (T,) to rows of ``image_ids`` (K,) (-1 where unknown).

    A dense lookup table when the ids are compact (the usual 1..K, at most 2K + 1024 entries), else a
    binary search over the sorted ids: memory never follows the largest id a (corrupt) file names.
    """
    top = int(image_ids.max())
    if top < 2 * image_ids.size + 1024:
        lookup = np.full(top + 2, -1, dtype=np.int64)
        lookup[image_ids] = np.arange(image_ids.size)
        return lambda img: lookup[np.clip(img, -1, top + 1)]
    order = np.argsort(image_ids, kind="stable")
    sorted_ids = image_ids[order]

    def rows(img: np.ndarray) -> np.ndarray:
        pos = np.minimum(np.searchsorted(sorted_ids, img), sorted_ids.size - 1)
        return np.where(sorted_ids[pos] == img, order[pos], -1)

    return rows
