"""What an installed pivotd ships besides its code (pivotd.data), the commands that install it (`pivotd init`,
`pivotd install-service`), the console scripts and `python -m` of the simulators, in-process."""

from __future__ import annotations

import importlib
import runpy
import sys
from pathlib import Path

import pytest
import yaml
from support import REPO

from pivotd.cli import main
from pivotd.config import load_config
from pivotd.data import DataDir, data_dir
from pivotd.sim.mock_gimbal import split_protocol


def test_data_dirs_are_the_trees_config_and_systemd_directories():
    assert (data_dir(DataDir.CONFIG) / "spot.yaml").read_bytes() == (REPO / "config" / "spot.yaml").read_bytes()
    assert (data_dir(DataDir.SYSTEMD) / "pivotd.service").read_bytes() == \
        (REPO / "systemd" / "pivotd.service").read_bytes()


def test_init_lists_every_shipped_config_as_a_template(capsys):
    assert main(["init", "--list"]) == 0
    names = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    assert names == sorted(p.stem for p in (REPO / "config").glob("*.yaml"))
    assert {"spot", "demo"} <= set(names)


def test_init_writes_the_template_and_refuses_to_overwrite_without_force(tmp_path, capsys):
    target = tmp_path / "etc" / "pivotd.yaml"
    assert main(["init", "--template", "spot", "--config", str(target)]) == 0
    assert target.read_bytes() == (REPO / "config" / "spot.yaml").read_bytes()
    assert sorted(p.name for p in target.parent.iterdir()) == ["pivotd.yaml"]  # spot's map comes over the bus
    target.write_text("edited\n")
    capsys.readouterr()
    assert main(["init", "--template", "spot", "--config", str(target)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"pivotd init: error: {target}: exists (--force overwrites)"
    assert target.read_text() == "edited\n"
    assert main(["init", "--template", "spot", "--config", str(target), "--force"]) == 0
    assert target.read_bytes() == (REPO / "config" / "spot.yaml").read_bytes()


def test_init_copies_the_demo_map_so_the_config_loads_as_it_is(tmp_path):
    target = tmp_path / "pivotd.yaml"
    assert main(["init", "--template", "demo", "--config", str(target)]) == 0
    assert (tmp_path / "demo_hallway_map.txt").read_bytes() == (REPO / "config" / "demo_hallway_map.txt").read_bytes()
    cfg = load_config(target)
    assert cfg.map.file == tmp_path / "demo_hallway_map.txt"
    assert cfg == load_config(target)  # and it is the demo config, byte for byte
    assert yaml.safe_load(target.read_text()) == yaml.safe_load((REPO / "config" / "demo.yaml").read_text())


def test_init_names_the_templates_when_one_is_unknown(tmp_path, capsys):
    assert main(["init", "--template", "spto", "--config", str(tmp_path / "x.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pivotd init: error: --template: no template 'spto' (templates: demo, ")
    assert "spot" in err
    assert not (tmp_path / "x.yaml").exists()


def _sections(text: str) -> dict[str, str]:
    """``install-service`` output split at its ``# /path`` header lines: path -> file text."""
    out: dict[str, list[str]] = {}
    current = None
    for line in text.splitlines(keepends=True):
        if line.startswith("# /") and line.strip().endswith((".service", ".conf")):
            current = line[2:].strip()
            out[current] = []
        elif current is not None:
            out[current].append(line)
    return {k: "".join(v) for k, v in out.items()}


def test_install_service_prints_the_unit_running_this_pivotd_and_the_sysusers_file(tmp_path, capsys):
    config = tmp_path / "my config.yaml"
    assert main(["install-service", "--config", str(config)]) == 0
    files = _sections(capsys.readouterr().out)
    assert list(files) == ["/etc/systemd/system/pivotd.service", "/etc/sysusers.d/pivotd.conf"]
    unit = files["/etc/systemd/system/pivotd.service"]
    exec_start = [line for line in unit.splitlines() if line.startswith("ExecStart=")]
    script = Path(sys.executable).parent / "pivotd"  # the venv's console script, not resolved through symlinks
    expected = str(script) if script.is_file() else f"{sys.executable} -m pivotd.cli"
    assert exec_start == [f'ExecStart={expected} run --config "{config}"']
    # the check before each start runs the same pivotd on the same config
    assert [line for line in unit.splitlines() if line.startswith("ExecStartPre=")] == \
        [f'ExecStartPre={expected} check --offline --config "{config}"']
    shipped = (REPO / "systemd" / "pivotd.service").read_text().splitlines()
    assert [line for line in unit.splitlines() if not line.startswith(("ExecStart=", "ExecStartPre="))] == \
        [line for line in shipped if not line.startswith(("ExecStart=", "ExecStartPre="))]
    assert files["/etc/sysusers.d/pivotd.conf"] == (REPO / "systemd" / "pivotd.sysusers").read_text()


def test_install_service_writes_both_files_under_the_prefix(tmp_path, capsys):
    assert main(["install-service", "--write", "--prefix", str(tmp_path), "--config", "/etc/pivotd/robot.yaml"]) == 0
    unit = (tmp_path / "etc/systemd/system/pivotd.service").read_text()
    assert "\nExecStart=" in unit and unit.count("ExecStart=") == 1
    assert " run --config /etc/pivotd/robot.yaml\n" in unit
    assert (tmp_path / "etc/sysusers.d/pivotd.conf").read_text() == \
        (REPO / "systemd" / "pivotd.sysusers").read_text()
    assert capsys.readouterr().out.splitlines() == [f"wrote {tmp_path}/etc/systemd/system/pivotd.service",
                                                    f"wrote {tmp_path}/etc/sysusers.d/pivotd.conf"]


@pytest.mark.parametrize(("module", "usage"), [("pivotd.sim.sim_pose", "usage: sim_pose"),
                                               ("pivotd.sim.mock_gimbal", "usage: mock_gimbal"),
                                               ("pivotd.sim.demo", "usage: demo")])
def test_python_m_of_a_simulator_runs_its_main(module, usage, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", [module, "--help"])
    monkeypatch.delitem(sys.modules, module, raising=False)  # as `python -m` finds it: not imported yet
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_module(module, run_name="__main__", alter_sys=True)
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.startswith(usage)


def test_mock_gimbal_splits_off_its_protocol():
    assert split_protocol(["--tcp", "127.0.0.1:0"]) == ("pivot", ["--tcp", "127.0.0.1:0"])
    assert split_protocol(["--log", "x", "--protocol", "mavlink", "--udp", "h:1"]) == \
        ("mavlink", ["--log", "x", "--udp", "h:1"])
    assert split_protocol(["--protocol=dynamixel"]) == ("dynamixel", [])
    with pytest.raises(SystemExit, match="--protocol must be one of pivot, mavlink, dynamixel; got 'serial'"):
        split_protocol(["--protocol", "serial"])


def test_console_scripts_name_callables_and_the_tools_call_the_same():
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10: pytest's own TOML reader
        import tomli as tomllib
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert set(scripts) == {"pivotd", "pivotd-mock-gimbal", "pivotd-sim-pose"}
    for target in scripts.values():
        module, func = target.split(":")
        assert callable(getattr(importlib.import_module(module), func))
    for tool, target in (("mock_gimbal", scripts["pivotd-mock-gimbal"]), ("sim_pose", scripts["pivotd-sim-pose"])):
        module, func = target.split(":")
        assert f"from {module} import {func}\n" in (REPO / "tools" / tool).read_text()
