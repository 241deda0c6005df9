"""`pivotd plan` with the map filters: occlusion on the FIF two_walls map, view-angle needs directions."""

import json
import math
import subprocess

import numpy as np
import pytest
from support import PYTHON, REPO, child_env

pytestmark = pytest.mark.slow  # subprocesses / real time

TWO_WALLS = REPO / "tests" / "data" / "fif" / "two_walls_points_w.txt"


def plan(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, "-m", "pivotd.cli", "plan", *args], capture_output=True, text=True,
                          env=child_env(), cwd=REPO, timeout=120)


def test_occlusion_keeps_no_landmark_behind_the_wall(tmp_path):
    # two_walls: wall A in the plane x = 2.5 (|y| <= 2.5, |z| <= 1), wall B in y = 2.5 (|x| <= 2.5).
    # Waypoints outside wall A look across it: every wall-B landmark is behind wall A from there.
    path = tmp_path / "path.csv"
    ys = np.linspace(-2.0, 2.0, 9)
    path.write_text("".join(f"4.5,{y:.3f},0.0\n" for y in ys))
    out = tmp_path / "plan.csv"
    pts = np.loadtxt(TWO_WALLS)
    alpha = math.radians(60) / 2
    res = plan("--map", str(TWO_WALLS), "--path", str(path), "--fov-deg", "60", "--lambda", "0",
               "--occlusion-voxel", "0.5", "--out", str(out), "--json")
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    behind_in_cone_total = 0
    for row in rows:
        cam, d, visible = row[1:4], row[4:7], int(row[7])
        rel = pts - cam
        in_cone = (rel @ d) >= math.cos(alpha) * np.linalg.norm(rel, axis=1)
        # Behind wall A: deeper than the grazing band (0.5 m) behind its plane, sight line through the wall.
        t = (cam[0] - 2.5) / (cam[0] - pts[:, 0])
        crosses = np.abs(cam[1] + t * (pts[:, 1] - cam[1])) <= 2.5
        behind = (pts[:, 0] < 2.0) & crosses
        behind_in_cone_total += int((in_cone & behind).sum())
        # The visible count only counts landmarks that are not hidden.
        assert visible <= int((in_cone & ~behind).sum())
        # (Rays grazing wall A's own voxels at shallow angles may hide a few of its landmarks: see the
        # grazing notes in pivotd/maps/occlusion.py; most of the near wall in the cone stays counted.)
        assert visible >= 0.75 * int((in_cone & (np.abs(pts[:, 0] - 2.5) < 1e-6)).sum())
    # The case is real: hidden landmarks do fall inside the planned cones, and are not counted.
    assert behind_in_cone_total > 0
    assert summary["waypoints"] == 9 and summary["visible_mean"] > 50

    # Without occlusion the same planner counts the hidden wall too.
    res2 = plan("--map", str(TWO_WALLS), "--path", str(path), "--fov-deg", "60", "--lambda", "0", "--json")
    assert json.loads(res2.stdout)["visible_mean"] > summary["visible_mean"]


def test_view_angle_filter_without_directions_is_a_clear_error(tmp_path):
    path = tmp_path / "path.csv"
    path.write_text("0,0,0\n1,0,0\n")
    res = plan("--map", str(TWO_WALLS), "--path", str(path), "--max-view-angle-deg", "60", "--json")
    assert res.returncode == 2 and res.stdout == ""
    assert "two_walls_points_w.txt" in res.stderr and "observation directions" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


def test_occupancy_needs_a_voxel_size(tmp_path):
    path = tmp_path / "path.csv"
    path.write_text("0,0,0\n")
    res = plan("--map", str(TWO_WALLS), "--path", str(path), "--occupancy", str(TWO_WALLS))
    assert res.returncode == 2 and "--occlusion-voxel" in res.stderr
