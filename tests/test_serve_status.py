"""The served run's state and clock as a PLC sees and drives them (issue 42): waiting for start(), pause() and
resume(), set_speed(), an event on every change of state, the KPIs served at the end and the server staying up in
state "finished" for its grace time; reset(seed) serving the batch of that seed.

The state-following client is node-opcua (tests/opcua_status_client.js); the expected KPIs are those the run
wrote to kpis.json, the expected batch the one sampled here from the scenario with that seed.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

pytest.importorskip("asyncua")
from asyncua import ua  # noqa: E402

from fishfmu.cosim.build import scenario_fish  # noqa: E402
from fishfmu.scenario import schema  # noqa: E402
from tests.test_serve import LAB, NODE_OPCUA, SERVED, connect, free_port  # noqa: E402

SHORT = ["--set", "fish.count=2", "--set", "run.duration_s=1", "--no-report", *LAB]


def _serve(out: Path, *extra: str) -> tuple[subprocess.Popen, str]:
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "fishfmu.cli", "serve", str(SERVED), "--endpoint", url, "--out",
                             str(out), *SHORT, *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, url


async def _listening(url: str, proc: subprocess.Popen) -> None:
    await (await connect(url, proc)).disconnect()


def test_node_opcua_follows_the_runs_state_by_its_events_and_sees_it_finish(tmp_path):
    if not (NODE_OPCUA / "node-opcua-client").is_dir() or shutil.which("node") is None:
        if os.environ.get("CI") == "true":
            pytest.fail(".ci/run installs node-opcua-client into .ci/node-opcua; it is missing")
        pytest.skip("node-opcua-client not installed (.ci/run installs it)")
    proc, url = _serve(tmp_path / "served", "--realtime", "2", "--wait-for-start", "--grace", "2")
    asyncio.run(_listening(url, proc))
    env = {**os.environ, "NODE_PATH": str(NODE_OPCUA), "HOME": str(tmp_path)}
    js = subprocess.run(["node", str(Path(__file__).parent / "opcua_status_client.js"), url], capture_output=True,
                        text=True, env=env, timeout=300)
    out, err = proc.communicate(timeout=120)
    assert js.returncode == 0, js.stderr
    seen = json.loads(next(line for line in js.stdout.splitlines() if line.startswith("RESULT "))[7:])
    # --wait-for-start: the line waits, at t = 0, until start(); methods the state does not allow are refused
    assert seen["waiting"] == "waiting" and seen["timeWaiting"] == 0.0
    assert seen["calls"] == {"stepInRealTime": "BadInvalidState", "resumeWhileWaiting": "BadInvalidState",
                             "start": "Good", "pause": "Good", "resume": "Good", "setSpeed": "Good",
                             "setSpeedTooFast": "BadInvalidArgument"}
    assert 0.0 < seen["tPaused"] == seen["tStillPaused"] < 1.0  # paused: the wall clock no longer steps it
    assert seen["factor"] == 4.0
    # every change of state an event, in order; the end is "finished" with the KPIs the run wrote
    assert seen["eventsAtEnd"] == ["run_state: running", "run_state: paused", "run_state: running",
                                   "run_state: finished"]
    assert seen["state"] == "finished" and seen["clock"]["time"] == pytest.approx(1.0)
    kpis = json.loads((tmp_path / "served" / "kpis.json").read_text())
    kpis = kpis.get("kpis", kpis)
    assert seen["kpis"] == {"fish_in": kpis["fish_in"], "lost": kpis["lost"]}
    info = json.loads((tmp_path / "served" / "run_info.json").read_text())
    assert seen["clock"]["lateSteps"] == info["served"]["pacing"]["overruns"]
    assert seen["clock"]["lagMax"] == pytest.approx(info["served"]["pacing"]["lateness_max_s"], abs=1e-6)
    # the server went after its grace time, the client still connected until then
    assert seen["lost"] is True and info["served"]["ended"] == "the scenario's end"


async def _reset_with_seed(url: str, proc: subprocess.Popen) -> dict:
    client = await connect(url, proc)
    try:
        idx = await client.get_namespace_index("urn:fishfmu")
        root = client.get_node(ua.NodeId("fishfmu", idx))
        node = lambda name: client.get_node(ua.NodeId(name, idx))  # noqa: E731
        seen = {"state": await node("fishfmu.run_state").read_value()}
        await root.call_method(ua.QualifiedName("step", idx), ua.Variant(3, ua.VariantType.Int32))
        await root.call_method(ua.QualifiedName("pause", idx))
        try:
            await root.call_method(ua.QualifiedName("step", idx), ua.Variant(1, ua.VariantType.Int32))
        except ua.UaStatusCodeError as exc:
            seen["step while paused"] = type(exc).__name__
        seen["t paused"] = await node("fishfmu.time_s").read_value()
        seen["kpi before the end"] = await node("fishfmu.kpis.fish_in").read_value()
        seen["t reset"] = await root.call_method(ua.QualifiedName("reset", idx), ua.Variant(7, ua.VariantType.UInt32))
        seen["state after reset"] = await node("fishfmu.run_state").read_value()
        await root.call_method(ua.QualifiedName("step", idx), ua.Variant(2, ua.VariantType.Int32))
        await root.call_method(ua.QualifiedName("stop", idx))
        return seen
    finally:
        with contextlib.suppress(ConnectionError, OSError, asyncio.TimeoutError):  # stop() ends the server
            await client.disconnect()


def test_in_lockstep_pause_refuses_steps_and_reset_with_a_seed_serves_that_seeds_batch(tmp_path):
    proc, url = _serve(tmp_path / "served", "--set", "fish.count=3")
    seen = asyncio.run(_reset_with_seed(url, proc))
    proc.communicate(timeout=120)
    assert seen["state"] == "running"
    assert seen["step while paused"] == "BadInvalidState" and seen["t paused"] == pytest.approx(0.03)
    assert math.isnan(seen["kpi before the end"])
    assert seen["t reset"] == 0.0 and seen["state after reset"] == "running"
    written = pd.concat(pd.read_csv(f) for f in sorted((tmp_path / "served" / "run" / "runs").glob("*/fish.csv")))
    expected = scenario_fish(schema.load_scenario(SERVED, {"fish.count": 3, "run.seed": 7}))
    other = scenario_fish(schema.load_scenario(SERVED, {"fish.count": 3}))
    assert written["length_m"].tolist() == [f.length_m for f in expected]
    assert written["length_m"].tolist() != [f.length_m for f in other]
    info = json.loads((tmp_path / "served" / "run_info.json").read_text())
    assert info["seed"] == 7 and info["served"]["resets"] == 1
