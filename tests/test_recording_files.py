"""Recordings are never overwritten: timestamped files, split by size or age, each carrying the run's config text
and map so that ``pivotd plot`` needs nothing else (pivotd/daemon/recorder.py, pivotd/viz/recording.py)."""

from __future__ import annotations

import datetime
import os
import re
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from support import PYTHON, REPO, ManagedProcess, free_tcp_port, wait_until

from pivotd.bus.messages import JOINT_STATE, ODOMETRY, encode_joint_state, encode_odometry
from pivotd.cli import main
from pivotd.config import load_config
from pivotd.daemon.recorder import (
    CONFIG_ATTACHMENT,
    MAP_METADATA_NAME,
    METADATA_NAME,
    Recorder,
    RecordingFiles,
    map_checksum,
    open_recording,
    record_run,
    resolve_recording,
)
from pivotd.errors import ConfigError, InputError
from pivotd.sim.launch import derive_config
from pivotd.viz.recording import read_recording

NAME = re.compile(r"run-\d{8}-\d{6}(-\d+)?\.mcap")
WHEN = datetime.datetime(2026, 12, 2, 1, 44, 0, tzinfo=datetime.timezone.utc)


def read(path: Path) -> tuple[list, dict, dict]:
    """(messages as (topic, sequence), metadata by name, attachments by name) of one MCAP file."""
    with path.open("rb") as fh:
        reader = make_reader(fh)
        messages = [(c.topic, m.sequence) for _, c, m in reader.iter_messages()]
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        attachments = {a.name: bytes(a.data) for a in reader.iter_attachments()}
    return messages, metadata, attachments


def joint(k: int) -> bytes:
    return encode_joint_state(k * 0.02, ["pan", "tilt"], [0.01 * k, 0.0], [0.5, 0.0])


def test_names_are_timestamped_new_files_and_an_existing_one_is_never_opened(tmp_path):
    files = RecordingFiles(tmp_path / "rec" / "run.mcap")
    first, fh1 = files.create(WHEN)
    fh1.write(b"first")
    fh1.close()
    second, fh2 = files.create(WHEN)  # the same second: another name
    fh2.close()
    later, fh3 = files.create(WHEN + datetime.timedelta(seconds=1))
    fh3.close()
    assert [first.name, second.name, later.name] == ["run-20261202-014400.mcap", "run-20261202-014400-2.mcap",
                                                     "run-20261202-014401.mcap"]
    assert first.read_bytes() == b"first"
    assert files.existing() == [first, second, later]  # oldest first, though "-2" sorts before "." as text
    (tmp_path / "rec" / "other-20261202-014500.mcap").write_bytes(b"")  # another target's: not ours
    assert RecordingFiles(tmp_path / "rec").existing() == [first, second, later]  # a directory: STEM "run"
    assert resolve_recording(tmp_path / "rec" / "run.mcap") == later
    with pytest.raises(InputError, match=r"^--record .*run-20261202-014400\.mcap: exists \(a recording never "
                                         r"overwrites a file\)$"):
        Recorder(first)
    assert first.read_bytes() == b"first"


def test_a_restart_starts_a_new_file_and_keeps_the_last_one(tmp_path):
    target = tmp_path / "run.mcap"
    for run in range(2):
        rec = open_recording(target)
        for k in range(50):
            rec.write("/pivot/joint_states", JOINT_STATE, joint(k + 100 * run))
        rec.close()
        assert rec.status()["state"] == "closed"
    files = RecordingFiles(target).existing()
    assert len(files) == 2 and all(NAME.fullmatch(f.name) for f in files) and not target.exists()
    for f in files:
        messages, _, _ = read(f)
        assert len(messages) == 50


def test_split_by_size_every_file_complete_with_the_header(tmp_path):
    config = derive_config(REPO / "config" / "demo.yaml", tmp_path / "run.yaml", {})
    cfg = load_config(config)
    rng = np.random.default_rng(1)
    payloads = [rng.bytes(100_000) for _ in range(40)]  # incompressible: 4 MB
    rec = open_recording(tmp_path / "rec/", max_bytes=1 << 20)
    record_run(rec, "demo", config, "9.9.9", cfg.map.file, cfg.record.map_max_bytes)
    for k, data in enumerate(payloads):
        rec.write("/blob", JOINT_STATE, data, log_time_ns=1_000_000_000 + k)
    rec.close()
    status = rec.status()
    files = RecordingFiles(tmp_path / "rec").existing()
    assert status["state"] == "closed" and status["files"] == len(files) >= 3, status
    assert status["path"] == str(files[-1]) and status["messages"] == 40
    assert status["bytes"] == sum(f.stat().st_size for f in files)
    sequences = []
    for part, f in enumerate(files, 1):
        messages, metadata, attachments = read(f)
        sequences += [seq for _, seq in messages]
        assert metadata[METADATA_NAME] == {"name": "demo", "config": str(config), "version": "9.9.9",
                                           "part": str(part)}
        assert attachments[CONFIG_ATTACHMENT] == config.read_bytes()
        assert attachments[f"map/{cfg.map.file.name}"] == cfg.map.file.read_bytes()
        assert metadata[MAP_METADATA_NAME]["sha256"] == map_checksum(cfg.map.file)[0]
        if f != files[-1]:  # finished at the first message past the limit
            assert (1 << 20) <= f.stat().st_size <= (1 << 20) + 2 * 100_000 + 200_000, f.stat().st_size
    assert sequences == list(range(40))  # nothing lost or repeated across the files


def test_split_by_age(tmp_path):
    rec = open_recording(tmp_path / "age.mcap", max_duration_s=1.0)
    k = 0

    def written_into_three_files() -> bool:
        nonlocal k
        rec.write("/pivot/joint_states", JOINT_STATE, joint(k))
        k += 1
        return rec.status()["files"] >= 3

    assert wait_until(written_into_three_files, 60, 0.05), rec.status()
    rec.close()
    files = RecordingFiles(tmp_path / "age.mcap").existing()
    assert len(files) == rec.status()["files"] >= 3
    assert sum(len(read(f)[0]) for f in files) == k == rec.status()["messages"]


def test_a_fifo_is_written_as_it_is(tmp_path):
    fifo = tmp_path / "rec.fifo"
    os.mkfifo(fifo)
    fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    try:
        rec = open_recording(fifo, max_bytes=1 << 20)
        assert rec.path == fifo and rec.status()["path"] == str(fifo)
        rec.close(timeout=0.5)  # nobody drains the pipe here: the state does not matter, the name does
    finally:
        os.close(fd)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.fifo"]


def write_run(tmp: Path, target: Path, map_max_bytes: int | None = None) -> tuple[Path, np.ndarray]:
    """A short recording made as the daemon makes it (header, poses, joint states) of a run whose config and
    map live in ``tmp/site``; returns the config and the map's landmarks."""
    site = tmp / "site"
    site.mkdir()
    rng = np.random.default_rng(5)
    landmarks = np.column_stack([np.full(300, 3.0), rng.uniform(-2, 12, 300), rng.uniform(0, 2, 300)])
    np.savetxt(site / "walls.txt", landmarks)
    config = derive_config(REPO / "config" / "demo.yaml", site / "run.yaml", {"name": "elsewhere",
                                                                             "map.file": "walls.txt"})
    cfg = load_config(config)
    rec = open_recording(target)
    record_run(rec, cfg.name, cfg.source, "1.0", cfg.map.file,
               cfg.record.map_max_bytes if map_max_bytes is None else map_max_bytes)
    t0 = 1_700_000_000_000_000_000
    quat = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])
    for k in range(60):
        t = k / 20
        rec.write("/odom", ODOMETRY, encode_odometry(t, "map", "base_link", np.array([0.0, t, 0.0]), quat),
                  log_time_ns=t0 + round(t * 1e9))
        rec.write("/pivot/joint_states", JOINT_STATE, encode_joint_state(t, ["pan", "tilt"], [0.1 * t, 0.0],
                                                                         [0.1, 0.0]), log_time_ns=t0 + round(t * 1e9))
    rec.close()
    return config, np.loadtxt(site / "walls.txt")


def test_a_recording_needs_nothing_else_on_another_machine(tmp_path):
    target = tmp_path / "out" / "run.mcap"
    config, landmarks = write_run(tmp_path, target)
    here = read_recording(target)  # the name given to --record finds the file
    assert here.cfg.source == config and here.cfg.name == "elsewhere"
    # "another machine": neither the config nor the map is where the recording says
    shutil.move(tmp_path / "site", tmp_path / "gone")
    there = read_recording(target)
    assert there.cfg.name == "elsewhere" and there.cfg.pivot.fov_deg == here.cfg.pivot.fov_deg
    assert there.cfg.motion == here.cfg.motion and there.cfg.gimbal.mount == here.cfg.gimbal.mount
    np.testing.assert_allclose(np.sort(there.landmarks, axis=0), np.sort(landmarks, axis=0), atol=1e-6)
    np.testing.assert_array_equal(there.pose_pos, here.pose_pos)
    # a config edited since the run: the recorded one is used, not the edited file
    shutil.move(tmp_path / "gone", tmp_path / "site")
    config.write_text(config.read_text().replace("name: elsewhere", "name: edited"))
    assert read_recording(target).cfg.name == "elsewhere"
    assert read_recording(target, config).cfg.name == "edited"  # unless --config says otherwise


def test_a_map_over_map_max_bytes_is_recorded_by_its_checksum_only(tmp_path):
    target = tmp_path / "out" / "run.mcap"
    config, landmarks = write_run(tmp_path, target, map_max_bytes=100)
    recorded = RecordingFiles(target).existing()[0]
    _, metadata, attachments = read(recorded)
    map_file = tmp_path / "site" / "walls.txt"
    assert metadata[MAP_METADATA_NAME] == {"file": str(map_file), "sha256": map_checksum(map_file)[0],
                                           "bytes": str(map_file.stat().st_size), "attached": "false",
                                           "files": '["map/walls.txt"]'}
    assert set(attachments) == {CONFIG_ATTACHMENT}
    config.unlink()  # the config is gone, the map is still here: the recorded config with this map
    np.testing.assert_allclose(np.sort(read_recording(target).landmarks, axis=0), np.sort(landmarks, axis=0),
                               atol=1e-6)
    map_file.unlink()
    with pytest.raises(InputError, match=r"the run's map .*walls\.txt is not in the recording \(over "
                                         r"record\.map_max_bytes\) and not here; pass --config FILE$"):
        read_recording(target)


def test_plot_draws_a_recording_whose_config_and_map_are_gone(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    target = tmp_path / "out" / "run.mcap"
    write_run(tmp_path, target)
    shutil.rmtree(tmp_path / "site")
    out = tmp_path / "fig.png"
    assert main(["plot", str(target), "-o", str(out), "--figure", "route"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_record_section_of_the_config(tmp_path):
    def load(text: str):
        path = tmp_path / "c.yaml"
        path.write_text("map: {allow_empty: true}\n" + text)
        return load_config(path).record

    r = load("record: {path: recs/, max_bytes: 2097152, max_duration_s: 600}\n")
    assert r.path == tmp_path / "recs" and r.max_bytes == 2 << 20 and r.max_duration_s == 600.0
    assert load("").path is None
    with pytest.raises(ConfigError, match=r"record\.max_bytes: must be 0 \(no limit\) or ≥ 1048576 \(1 MiB\), "
                                          r"got 1000$"):
        load("record: {max_bytes: 1000}\n")
    with pytest.raises(ConfigError, match=r"record\.max_duration_s: must be 0 \(no limit\) or ≥ 1 s, got 0\.5$"):
        load("record: {max_duration_s: 0.5}\n")
    with pytest.raises(ConfigError, match=r"record\.maxbytes"):
        load("record: {maxbytes: 1}\n")


def test_the_time_in_the_name_is_utc(tmp_path):
    local = WHEN.astimezone(datetime.timezone(datetime.timedelta(hours=5)))  # 06:44 there
    path, fh = RecordingFiles(tmp_path / "x.mcap").create(local)
    fh.close()
    assert path.name == "x-20261202-014400.mcap"


@pytest.mark.slow
def test_the_daemon_records_to_record_path_and_a_restart_keeps_the_first_recording(tmp_path):
    config = derive_config(REPO / "config" / "demo.yaml", tmp_path / "pivotd.yaml",
                           {"zenoh.listen": [f"tcp/127.0.0.1:{free_tcp_port()}"], "gimbal.port": "mock://",
                            "record.path": "recs/"})
    for _ in range(2):
        with ManagedProcess([PYTHON, "-m", "pivotd.cli", "--config", str(config)], "pivotd") as daemon:
            assert daemon.wait_stderr(" ready: ", 60), daemon.output()
            assert daemon.wait_stderr(f"recording to {tmp_path / 'recs'}/run-", 0), daemon.output()
            assert daemon.stop(signal.SIGTERM, timeout=30) == 0, daemon.output()
    files = RecordingFiles(tmp_path / "recs").existing()
    assert len(files) == 2 and all(NAME.fullmatch(f.name) for f in files), files
    for f in files:  # both complete (a summary: finished cleanly), both with the run's config
        with f.open("rb") as fh:
            assert make_reader(fh).get_summary() is not None
        _, metadata, attachments = read(f)
        assert metadata[METADATA_NAME]["part"] == "1" and attachments[CONFIG_ATTACHMENT] == config.read_bytes()
