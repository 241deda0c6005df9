"""One source of defaults: the config dataclasses. The loader and docs/CONFIG.md must agree with them.

Every key documented in CONFIG.md with a literal default (in backticks) is written into a config with that
value; loading it must give exactly the config that leaving the key out gives, which must be ``Config()``.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from pivotd.config import Config, SimConfig, load_config

REPO = Path(__file__).resolve().parent.parent
CONFIG_MD = REPO / "docs" / "CONFIG.md"
BASE = {"map": {"allow_empty": True}}


def documented_defaults() -> list[tuple[str, object]]:
    """(dotted YAML key, default) for every table row of CONFIG.md whose default is a literal in backticks."""
    out = []
    section = None
    for line in CONFIG_MD.read_text().splitlines():
        heading = re.fullmatch(r"## `(\w+)`.*", line)
        if heading:
            section = heading[1]
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if line.startswith("|") else []
        if section is None or len(cells) < 3 or cells[0] in ("key", "---"):
            continue
        keys = re.findall(r"`([\w.]+)`", cells[0])
        defaults = re.findall(r"`([^`]*)`", cells[1])
        if not defaults:
            continue  # none / — / a description: no literal default
        assert len(keys) == len(defaults), f"CONFIG.md row {line!r}: {len(keys)} keys, {len(defaults)} defaults"
        for key, text in zip(keys, defaults, strict=True):
            dotted = key if section == "name" else f"{section}.{key}"
            out.append((dotted, yaml.safe_load(text)))
    return out


def _load(tmp_path: Path, doc: dict, name: str) -> Config:
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return replace(load_config(path), source=None)


def _with(doc: dict, dotted: str, value: object) -> dict:
    out = yaml.safe_load(yaml.safe_dump(doc))
    node = out
    *parents, last = dotted.split(".")
    for k in parents:
        node = node.setdefault(k, {})
    node[last] = value
    return out


DOCUMENTED = documented_defaults()


def test_the_doc_documents_every_section_with_defaults():
    sections = {k.split(".")[0] for k, _ in DOCUMENTED}
    assert sections == {"name", "zenoh", "topics", "map", "pivot", "planner", "gimbal", "motion", "control",
                        "logging", "pose_gate", "sim", "ros", "record"}
    assert len(DOCUMENTED) >= 50


def test_loaded_defaults_are_the_dataclass_defaults(tmp_path):
    loaded = _load(tmp_path, BASE, "minimal")
    expected = Config(map=replace(Config().map, allow_empty=True))
    assert loaded == expected
    # The joint limits are ±170° pan, ±90° tilt both ways (they once differed).
    assert Config().gimbal.limits == loaded.gimbal.limits
    assert _load(tmp_path, {**BASE, "sim": {}}, "sim").sim == SimConfig()


@pytest.mark.parametrize(("key", "value"), DOCUMENTED, ids=[k for k, _ in DOCUMENTED])
def test_documented_default_is_the_real_default(tmp_path, key, value):
    base = {**BASE, "sim": {}} if key.startswith("sim.") else BASE
    if key == "map.allow_empty":  # its default (false) needs a map file
        base = {"map": {"file": str(REPO / "config" / "demo_hallway_map.txt")}}
    documented = _load(tmp_path, _with(base, key, value), "documented")
    assert documented == _load(tmp_path, base, "default"), f"docs/CONFIG.md: {key} default {value!r} is not the default"


def test_a_wrong_documented_default_would_be_caught(tmp_path):
    """The comparison above is not vacuous: a value other than the default changes the loaded config."""
    assert _load(tmp_path, _with(BASE, "gimbal.limits.pan_max_deg", 180), "x") != _load(tmp_path, BASE, "d")
    assert _load(tmp_path, _with(BASE, "pivot.fov_deg", 61), "y") != _load(tmp_path, BASE, "d")
