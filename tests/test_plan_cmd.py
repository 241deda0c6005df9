"""``pivotd plan`` end to end (subprocess) on the FIF files, and its bad-input contract."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pivotd.geometry import normalize
from pivotd.pivot.visibility import hard_count

pytestmark = pytest.mark.slow  # subprocesses / real time

REPO = Path(__file__).resolve().parent.parent
FIF = REPO / "tests" / "data" / "fif"
MAP = FIF / "ycorridor_6x20_points_w.txt"
PATH = FIF / "ycorridor_6x20.csv"


def _plan(*args, timeout=120):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "pivotd.cli", "plan", *map(str, args)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO,
    )
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, out, err


@pytest.fixture(scope="module")
def fif_plan(tmp_path_factory):
    out = tmp_path_factory.mktemp("plan") / "plan.csv"
    code, stdout, stderr = _plan("--map", MAP, "--path", PATH, "--json", "--out", out)
    assert code == 0, stderr
    return json.loads(stdout), out


def test_json_summary_on_fif(fif_plan):
    summary, _ = fif_plan
    for key in ("waypoints", "landmarks", "fov_deg", "lambda", "optimize_s", "visible_mean", "max_step_deg"):
        assert key in summary
    assert summary["waypoints"] == 498 and summary["landmarks"] == 995
    assert summary["fov_deg"] == 30.0 and summary["lambda"] == 0.6
    assert 0 < summary["optimize_s"] < 60
    assert summary["visible_mean"] > 300
    assert summary["max_step_deg"] < 15


def test_csv_rows_are_consistent_with_the_inputs(fif_plan):
    summary, out = fif_plan
    lines = out.read_text().splitlines()
    assert lines[0] == "i,x,y,z,dx,dy,dz,visible"
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    assert rows.shape == (498, 8)
    assert np.array_equal(rows[:, 0], np.arange(498))
    assert np.allclose(np.linalg.norm(rows[:, 4:7], axis=1), 1, atol=1e-6)
    assert rows[:, 7].mean() == pytest.approx(summary["visible_mean"])
    pts = np.loadtxt(MAP, comments="#")
    for i in (0, 100, 250, 497):
        k = normalize(pts - rows[i, 1:4])
        assert abs(hard_count(rows[i, 4:7], k, np.radians(15)) - rows[i, 7]) <= 1


def test_lambda_zero_and_range_filter_and_summary_text(tmp_path):
    code, out, err = _plan("--map", MAP, "--path", PATH, "--lambda", "0", "--max-range", "6", "--fov-deg", "40")
    assert code == 0, err
    assert "498 waypoints" in out and "995 landmarks" in out
    code, out, err = _plan("--map", MAP, "--path", PATH, "--lambda", "0", "--max-range", "6", "--json")
    summary = json.loads(out)
    assert summary["lambda"] == 0.0
    assert summary["max_step_deg"] > 30  # independent waypoints jump between walls
    assert summary["visible_mean"] < 200  # only landmarks within 6 m count


def test_weights_from_column(tmp_path):
    pts = np.array([[5.0, 0.5, 0.0]] * 30 + [[-5.0, 0.0, 0.0]] * 10)
    w = np.r_[np.ones(30), np.full(10, 10.0)]
    m = tmp_path / "m.txt"
    np.savetxt(m, np.column_stack([pts, w]))
    p = tmp_path / "p.csv"
    p.write_text("0,0,0\n")
    out = tmp_path / "o.csv"
    for mode, sign in (("4", -1), ("none", 1), ("auto", -1)):
        code, _, err = _plan("--map", m, "--path", p, "--lambda", "0", "--weights-from", mode, "--out", out)
        assert code == 0, err
        dx = float(out.read_text().splitlines()[1].split(",")[4])
        assert np.sign(dx) == sign, mode
    m3 = tmp_path / "m3.txt"
    np.savetxt(m3, pts)
    code, _, err = _plan("--map", m3, "--path", p, "--weights-from", "w")
    assert code == 2 and "m3.txt" in err and len(err.strip().splitlines()) == 1
    named = tmp_path / "named.csv"  # a header naming the weight column: the column --weight-property names
    named.write_text("x,y,z,score\n" + "".join(f"{a},{b},{c},{e}\n" for (a, b, c), e in zip(pts, w, strict=True)))
    code, _, err = _plan("--map", named, "--path", p, "--lambda", "0", "--weights-from", "w",
                         "--weight-property", "score", "--out", out)
    assert code == 0, err
    assert float(out.read_text().splitlines()[1].split(",")[4]) < 0  # weighted: the 10 heavy landmarks win
    code, _, err = _plan("--map", named, "--path", p, "--weights-from", "w")
    assert code == 2 and "needs a weight column" in err


def _bad(tmp_path, name, text):
    f = tmp_path / name
    f.write_text(text)
    return f


@pytest.mark.parametrize(
    ("case", "expect"),
    [
        ("missing_map", "nope.txt"),
        ("wrong_columns", ":3"),
        ("nan_row", ":2"),
        ("empty_map", "empty"),
        ("empty_path", "empty"),
        ("unknown_ext", "unknown"),
        ("fov_zero", "--fov-deg"),
        ("fov_180", "--fov-deg"),
        ("bad_path_row", ":2"),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, case, expect):
    good_map = _bad(tmp_path, "map.txt", "1 2 3\n4 5 6\n")
    good_path = _bad(tmp_path, "path.csv", "0,0,0\n1,0,0\n")
    args = {"--map": good_map, "--path": good_path}
    extra = []
    if case == "missing_map":
        args["--map"] = tmp_path / "nope.txt"
    elif case == "wrong_columns":
        args["--map"] = _bad(tmp_path, "m.txt", "# header\n1 2 3\n1 2\n")
    elif case == "nan_row":
        args["--map"] = _bad(tmp_path, "m.txt", "1 2 3\nnan 2 3\n")
    elif case == "empty_map":
        args["--map"] = _bad(tmp_path, "m.txt", "# nothing\n")
    elif case == "empty_path":
        args["--path"] = _bad(tmp_path, "p.csv", "# nothing\n")
    elif case == "unknown_ext":
        args["--map"] = _bad(tmp_path, "m.foo", "1 2 3\n")
    elif case == "fov_zero":
        extra = ["--fov-deg", "0"]
    elif case == "fov_180":
        extra = ["--fov-deg", "180"]
    elif case == "bad_path_row":
        args["--path"] = _bad(tmp_path, "p.csv", "0,0,0\n1,inf,0\n")
    flat = [v for kv in args.items() for v in kv]
    code, out, err = _plan(*flat, *extra, "--json")
    assert code == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert expect in lines[0]
    if case not in ("fov_zero", "fov_180"):
        assert (".txt" in lines[0]) or (".csv" in lines[0]) or (".foo" in lines[0])
