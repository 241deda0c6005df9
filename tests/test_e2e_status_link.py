"""``pivotd status`` shows the gimbal link's decode drops of a real daemon whose simulated gimbal flips bits."""

from __future__ import annotations

import json
import subprocess

import pytest
from support import PYTHON, REPO, child_env, free_tcp_port, wait_until
from test_e2e_daemon import start_daemon, start_mock_gimbal, write_config

from pivotd.bus.session import open_session
from pivotd.bus.topics import status_key_for
from pivotd.cli.status import format_table, link_drops, query_status

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]


def test_status_table_and_json_carry_the_link_decode_drops(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    mock, url, _ = start_mock_gimbal(tmp_path, "--corrupt", "0.1", "--seed", "5")
    config = write_config(tmp_path, endpoint, url)
    with mock, start_daemon(config) as daemon:
        session = open_session(connect=[endpoint])
        try:
            docs: dict[str, dict] = {}

            def dropped() -> bool:
                docs.update(query_status(session, status_key_for("demo"), 1.0))
                return "demo" in docs and docs["demo"].get("link_counters", {}).get("decode_drops", 0) >= 3

            assert wait_until(dropped, 40), daemon.output()
        finally:
            session.close()
        doc = docs["demo"]
        counters = doc["link_counters"]
        reasons = link_drops(doc)
        assert sum(reasons.values()) == counters["decode_drops"] and reasons.get("crc", 0) == counters["crc_errors"]
        lines = format_table(docs).splitlines()
        assert lines[0].split()[-2:] == ["LINK", "DROPS"] and lines[1].split()[-1] == str(counters["decode_drops"])
        detail = ", ".join(f"{k} {v}" for k, v in reasons.items())
        assert f"demo: gimbal link: {counters['decode_drops']} frames dropped ({detail})" in lines
        # the CLI itself, a moment later: the counters only grow
        r = subprocess.run([PYTHON, "-m", "pivotd.cli", "status", "--connect", endpoint, "--name", "demo", "--json"],
                           capture_output=True, text=True, env=child_env(), cwd=str(REPO), timeout=60)
        assert r.returncode == 0, r.stderr
        later = json.loads(r.stdout)["link_counters"]
        assert later["decode_drops"] >= counters["decode_drops"] and later["drop_crc"] >= counters["drop_crc"]
