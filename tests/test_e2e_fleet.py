"""A fleet on one Zenoh router: three real daemons, each under its own ROS namespace and status key, two
simulated robots publishing poses; no cross-talk, and ``pivotd status`` lists each robot as itself.

The router is a zenoh-python session in router mode on loopback (what ``zenohd`` does, without the binary).
"""

from __future__ import annotations

import json
import subprocess

import pytest
from bus_support import open_client, open_router
from support import PYTHON, REPO, ManagedProcess, child_env, free_tcp_port, wait_until

from pivotd.cli.status import ALL_KEY, query_status
from pivotd.sim.launch import derive_config

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

DEMO = REPO / "config" / "demo.yaml"
ROBOTS = ("robot1", "robot2", "robot3")
WITH_POSES = ("robot1", "robot2")  # robot3 has no pose publisher: it must stay without a pose


def status_cli(endpoint: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, "-m", "pivotd.cli", "status", "--connect", endpoint, *args], capture_output=True,
                          text=True, env=child_env(), cwd=str(REPO), timeout=60)


def test_three_daemons_on_one_router_without_cross_talk(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    router = open_router(endpoint)
    procs: list[ManagedProcess] = []
    client = None
    try:
        for robot in ROBOTS:
            config = derive_config(DEMO, tmp_path / f"{robot}.yaml", {
                "name": robot, "zenoh.mode": "client", "zenoh.listen": [], "zenoh.connect": [endpoint],
                "topics": {"namespace": f"/{robot}", "frame_id": "map"}, "gimbal.port": "mock://",
                "planner.replan_hz": 2})
            procs.append(ManagedProcess([PYTHON, "-m", "pivotd.cli", "--config", str(config)], robot))
        for robot in WITH_POSES:
            procs.append(ManagedProcess([PYTHON, str(REPO / "tools" / "sim_pose"), "--route", "hallway", "--mode",
                                         "client", "--connect", endpoint, "--rate", "20", "--quiet", "--loop",
                                         "--odom-topic", f"/{robot}/odom", "--path-topic", f"/{robot}/plan"],
                                        f"sim_{robot}"))
        client = open_client(endpoint)
        docs: dict[str, dict] = {}

        def fleet_up() -> bool:
            docs.clear()
            docs.update(query_status(client, ALL_KEY, 1.0))
            return set(docs) == set(ROBOTS) and all(
                docs[r].get("state") == "tracking" and (docs[r].get("planner") or {}).get("plans", 0) > 0
                for r in WITH_POSES) and all(docs[r].get("state") == "waiting"  # started, not "starting"
                                             for r in ROBOTS if r not in WITH_POSES)

        ok = wait_until(fleet_up, 120, interval=0.5)
        assert ok, f"{json.dumps(docs)[:3000]}\n" + "\n".join(p.output() for p in procs)

        for robot in ROBOTS:
            doc = docs[robot]
            assert doc["name"] == robot
            topics = set(doc["bus"])
            # every input topic the daemon counts lives under its own namespace, none under another robot's
            assert topics and all(t.startswith(f"/{robot}/") for t in topics), topics
            received = doc["bus"][f"/{robot}/odom"]["received"]
            if robot in WITH_POSES:
                odom = doc["bus"][f"/{robot}/odom"]
                # Every pose of its own robot was taken: accepted, or replaced by a newer one before decoding
                # (newest-only input), or in flight (queued or decoding, at most two) when the status was
                # written. Nothing else dropped.
                drops = {k for k, v in odom.items() if k.startswith("dropped_") and v}
                assert received > 0 and odom["accepted"] > 0 and not drops, odom
                assert received - 2 <= odom["accepted"] + odom.get("superseded", 0) <= received, odom
                assert doc["pose_age_s"] is not None
                assert doc["planner"]["visible_now"] is not None
            else:
                assert received == 0 and doc["pose_age_s"] is None and doc["state"] == "waiting"
                assert doc["planner"]["plans"] == 0

        one = status_cli(endpoint, "--name", "robot2", "--json")
        assert one.returncode == 0, one.stderr
        doc = json.loads(one.stdout)
        assert doc["name"] == "robot2" and set(doc["bus"]) <= {f"/robot2/{t}" for t in (
            "odom", "plan", "pivot/landmarks", "pivot/targets")}

        every = status_cli(endpoint, "--all")
        assert every.returncode == 0, every.stderr
        lines = every.stdout.splitlines()
        assert lines[0].split()[:3] == ["NAME", "STATE", "LINK"]
        rows = {line.split()[0]: line.split() for line in lines[1:4]}
        assert set(rows) == set(ROBOTS)
        assert rows["robot1"][1] == "tracking" and rows["robot3"][1] == "waiting"
        assert rows["robot3"][3] == "-"  # no pose, no pose age

        watched = status_cli(endpoint, "--all", "--json", "--watch", "0.2", "--count", "2")
        assert watched.returncode == 0, watched.stderr
        snapshots = [json.loads(line) for line in watched.stdout.splitlines()]
        assert len(snapshots) == 2 and all(set(s) == set(ROBOTS) for s in snapshots)

        nobody = status_cli(endpoint, "--name", "robot9", "--timeout", "0.5")
        assert nobody.returncode == 2
        assert nobody.stderr.strip().splitlines() == [
            f"pivotd status: error: no pivotd answered on pivot/robot9/status within 0.5 s (asked via {endpoint})"]
    finally:
        if client is not None:
            client.close()
        for proc in procs:
            proc.kill()
        router.close()
