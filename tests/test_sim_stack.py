"""The end-to-end runner's inputs: the route a config names, the run's time budget, derived configs."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from pivotd.config import load_config
from pivotd.pivot.scenes import hallway
from pivotd.robot_path import Polyline
from pivotd.sim.launch import derive_config
from pivotd.sim.stack import config_route, route_duration

REPO = Path(__file__).resolve().parent.parent
DEMO = REPO / "config" / "demo.yaml"


def test_demo_config_walks_the_hallway():
    assert config_route(load_config(DEMO)) == "hallway"


def test_sim_route_of_a_config_is_its_csv_and_survives_derivation(tmp_path):
    conf = tmp_path / "conf"
    conf.mkdir()
    (conf / "route.csv").write_text("x,y,z\n0,0,0.7\n3,4,0.7\n")
    doc = yaml.safe_load(DEMO.read_text())
    doc["map"]["file"] = str(REPO / "config" / "demo_hallway_map.txt")
    doc["sim"]["route"] = "route.csv"  # relative to the config file
    (conf / "base.yaml").write_text(yaml.safe_dump(doc))
    route = config_route(load_config(conf / "base.yaml"))
    assert route == f"csv:{conf / 'route.csv'}"
    assert route_duration(route, 2.0) == pytest.approx(2.5)
    elsewhere = tmp_path / "other"
    elsewhere.mkdir()
    derived = derive_config(conf / "base.yaml", elsewhere / "d.yaml", {"gimbal.port": "mock://"})
    assert config_route(load_config(derived)) == f"csv:{(conf / 'route.csv').resolve()}"


def test_route_duration_of_the_hallway_and_of_a_timed_route(tmp_path):
    assert route_duration("hallway", 1.2) == pytest.approx(Polyline(hallway().path).length / 1.2)
    csv = tmp_path / "timed.csv"
    csv.write_text("t,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n4,0,0,0,0,0,0,1\n9,1,0,0,0,0,0,1\n")
    assert route_duration(f"csv:{csv}", 1.0, timed=True) == pytest.approx(9.0)
    assert route_duration(f"csv:{csv}", 0.5, timed=False) == pytest.approx(2.0)  # by arc length: 1 m at 0.5 m/s
