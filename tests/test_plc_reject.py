"""A PLC over OPC UA runs the controller FMU's reject logic in lockstep and gives the same run (issue 32).

``scenarios/reject_doubles.toml``: a camera ``cam`` over belt c4, a reject gate ``gate`` at its end, and the controller
FMU firing the gate (``controller.reject -> plant.gate.command``, reject_mode 1: doubles).  Here the reject logic
moves into a PLC written with asyncua's client: the served variant keeps the controller FMU for the belts
(``reject_mode = 0``), drops its wire to the gate and makes ``plant.gate.command`` an ``[opcua]`` input.  The PLC
is a transcription of ``update_reject``/``schedule_reject`` in fishfmu/fmu/sources/singulation_controller/model.c
(see its header comment); the run it drives must be the run of the original scenario with the FMU rejecting.

**Where the scan boundary lies.**  The scenario is Gauss-Seidel in the order controller -> drives -> plant
(``fishfmu check``): in the step from t_n = n dt to t_n + dt the controller FMU steps first and runs its scan n + 1
(``model_do_step`` runs the scan due at the step's end), reading the plant's outputs at t_n (the camera: one step
late) and ``drive_c4.belt_speed`` as drive_c4 left it at the end of the step before, also t_n (a feedback link: the
controller steps before the drive); its ``reject`` is used by the plant in that same step.  Scan 0 runs at
initialisation on the start values (belt at rest, ``cam_results`` 0: what the served line shows at t = 0).  After the
client's n-th ``step(1)`` the served line shows exactly those values of t_n (``plant.cam.*``, ``drive_c4.belt_speed``:
an FMU output as the FMU left it, not ``controller.belt_speed_4``, which shows the value *sent* in the step just
made, one step older), and a value written now is taken before the next step and used by the plant in it.  So the
PLC's scan n + 1 lies between its n-th and (n+1)-th ``step(1)``: read, scan, write, step.  The test checks the
boundary too: after each step the controller's inputs as sent in it (``controller.cam_results``,
``controller.belt_speed_4``) equal what the PLC read for the scan it just ran.
"""

from __future__ import annotations

import asyncio
import json
import re
import subprocess
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
import pytest

asyncua = pytest.importorskip("asyncua")
from asyncua import ua  # noqa: E402

from plant.contract.kpis import KPI_KEYS  # noqa: E402
from tests.test_serve import LAB, connect, free_port  # noqa: E402

ROOT = Path(__file__).parents[1]
SCENARIO = ROOT / "scenarios" / "reject_doubles.toml"
GATE = "plant.gate.command"
# 6 fish, 20 s: seed 4 has a double reach the gate at ~18.3 s (seed 1 has none by then, seeds 2 and 3 only at ~19.5 s)
SHORT = ["--set", "fish.count=6", "--set", "run.duration_s=20", "--set", "run.seed=4", "--no-report"]
CAMERA = ["plant.cam.lead_double", "plant.cam.lead_x", "plant.cam.lead_length", "plant.cam.lead_heading",
          "plant.cam.results"]
SPEED = "drive_c4.belt_speed"  # wired to controller.belt_speed_4 (reject_belt = 4)
SENT = ["controller.cam_double", "controller.cam_lead_x", "controller.cam_lead_length", "controller.cam_lead_heading",
        "controller.cam_results", "controller.belt_speed_4"]
MAX_WINDOWS = 32
TRAVEL_TOLERANCE_M = 1e-9


@dataclass
class RejectLogic:
    """update_reject/schedule_reject of model.c in Python, operation for operation (the same floating-point sums)."""

    mode: int
    reject_x: float
    camera_latency: float
    actuator_time: float
    reject_length: float
    reject_margin: float
    scan_time: float
    k: int = -1
    travel_m: float = 0.0
    last_results: int = 0
    windows: list[list[float]] = field(default_factory=list)  # [open, close] in travel, in the order scheduled
    events: int = 0

    def scan(self, double: bool, lead_x: float, length: float, heading: int, results: int, v: float) -> bool:
        """One scan on the inputs as read: the command of the device until the next scan."""
        self.k += 1
        new_result = self.k > 0 and results != self.last_results
        if self.k > 0:
            self.travel_m += v * self.scan_time
        self.last_results = results
        kept = [w for w in self.windows if w[1] + TRAVEL_TOLERANCE_M >= self.travel_m]
        self.windows = [] if self.mode == 0 else kept
        calls = (self.mode >= 1 and double) or (self.mode == 2 and heading == -1)
        if new_result and calls and length > 0.0:
            self.schedule(lead_x, length, v)
        return any(w[0] <= self.travel_m + TRAVEL_TOLERANCE_M and self.travel_m <= w[1] + TRAVEL_TOLERANCE_M
                   for w in self.windows)

    def schedule(self, lead_x: float, length: float, v: float) -> None:
        front_now_m = lead_x + v * self.camera_latency
        to_go_m = self.reject_x - front_now_m
        open_m = self.travel_m + to_go_m - self.reject_margin - v * self.actuator_time
        close_m = self.travel_m + to_go_m + length + self.reject_length + self.reject_margin
        if close_m + TRAVEL_TOLERANCE_M < self.travel_m:
            return  # the fish is past the device already
        last = self.windows[-1] if self.windows else None
        overlaps = (last is not None and open_m <= last[1] + TRAVEL_TOLERANCE_M
                    and close_m + TRAVEL_TOLERANCE_M >= last[0])
        if not overlaps and len(self.windows) < MAX_WINDOWS:
            self.windows.append([open_m, close_m])
            self.events += 1
            return
        last[0], last[1] = min(last[0], open_m), max(last[1], close_m)


def served_variant(tmp_path: Path) -> Path:
    """reject_doubles.toml with the controller FMU not rejecting and the gate written over OPC UA."""
    text = SCENARIO.read_text()
    text, n_mode = re.subn(r"(?m)^reject_mode = 1\b", "reject_mode = 0", text)
    text, n_wire = re.subn(r'(?m)^\s*"controller\.reject -> plant\.gate\.command",[^\n]*\n', "", text)
    text, n_opcua = re.subn(r"(?m)^\[wiring\]$", f'[opcua]\ninputs = ["{GATE}"]\n\n[wiring]', text)
    assert (n_mode, n_wire, n_opcua) == (1, 1, 1), "reject_doubles.toml changed: the edits below no longer apply"
    path = tmp_path / "reject_plc.toml"
    path.write_text(text)
    return path


def reject_parameters() -> dict:
    """The reject parameters of the controller FMU in the scenario; the PLC scans every communication step."""
    scenario = tomllib.loads(SCENARIO.read_text())
    params = next(f for f in scenario["fmu"] if f["name"] == "controller")["parameters"]
    assert params["reject_mode"] == 1 and params["reject_belt"] == 4
    assert "scan_time" not in params  # variables.toml's 10 ms: one scan per communication step
    assert scenario["run"]["comm_step_s"] == 0.01
    return {"mode": 1, "scan_time": 0.01, **{k: float(params[k]) for k in ("reject_x", "camera_latency",
                                                                          "actuator_time", "reject_length",
                                                                          "reject_margin")}}


async def plc(url: str, proc: subprocess.Popen) -> dict:
    """The PLC in lockstep: scan 0 on the values at t = 0, then per step: scan n + 1 on the values after step n,
    write the gate, step."""
    client = await connect(url, proc)
    try:
        idx = await client.get_namespace_index("urn:fishfmu")
        node = lambda name: client.get_node(ua.NodeId(name, idx))  # noqa: E731
        folder, state, gate = node("fishfmu"), node("fishfmu.run_state"), node(GATE)
        reads = [node(name) for name in [*CAMERA, SPEED, *SENT, "fishfmu.run_state"]]
        logic = RejectLogic(**reject_parameters())
        values = await client.read_values(reads)
        assert values[-1] == "running" and values[4] == 0 and values[5] == 0.0  # the FMU's start values at scan 0
        logic.scan(*values[:6])
        commands, mismatches, written, t = [], [], False, 0.0
        while values[-1] == "running":
            used = values[:6]
            command = logic.scan(*used)  # scan n + 1, n = the steps made so far
            if command != written:  # the server holds the value last written; a write per change is enough
                await gate.write_value(ua.Variant(command, ua.VariantType.Boolean))
                written = command
            commands.append(command)
            t = await folder.call_method(ua.QualifiedName("step", idx), ua.Variant(1, ua.VariantType.Int32))
            values = await client.read_values(reads)
            if values[6:12] != used:  # what the controller FMU was sent in this step: what the scan read
                mismatches.append((t, used, values[6:12]))
        ended = await state.read_value()
        await folder.call_method(ua.QualifiedName("stop", idx))
        return {"t": t, "commands": commands, "mismatches": mismatches, "events": logic.events, "state": ended}
    finally:
        await client.disconnect()


def test_a_plc_running_the_reject_logic_over_opc_ua_gives_the_run_of_the_controller_fmu(tmp_path):
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "fishfmu.cli", "serve", str(served_variant(tmp_path)), "--endpoint",
                             url, "--out", str(tmp_path / "served"), *SHORT, *LAB], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        seen = asyncio.run(plc(url, proc))
        out, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    ref = subprocess.run([sys.executable, "-m", "fishfmu.cli", "run", str(SCENARIO), "--out", str(tmp_path / "ref"),
                          *SHORT], capture_output=True, text=True)
    # 6 fish in 20 s do not all leave: the scenario's [expect] (lost <= 0) fails, exit 1, for both
    assert proc.returncode == ref.returncode == 1, (err, ref.stderr)
    assert seen["state"] == "finished" and seen["t"] == pytest.approx(20.0) and len(seen["commands"]) == 2000
    assert seen["mismatches"] == []  # the scan boundary: each scan read what the controller FMU read in its scan
    # what that boundary rests on, as the reference run states it: the controller steps first; the camera and the
    # drive's speed reach it one step late; its reject reaches the plant in the same step
    wiring = json.loads((tmp_path / "ref" / "run_info.json").read_text())["wiring"]
    assert wiring["coupling"] == "gauss-seidel" and wiring["stepping_order"][0] == "controller"
    assert wiring["stepping_order"][-1] == "plant"
    delayed = {link["connection"] for link in wiring["delayed_links"]}
    assert {f"{a} -> {b}" for a, b in zip([*CAMERA, SPEED], SENT)} <= delayed
    assert "controller.reject -> plant.gate.command" not in delayed

    # the gate, step by step: the PLC's command (as the served line took it) is the controller FMU's
    ref_signals = pd.read_csv(tmp_path / "ref" / "signals.csv")
    served_signals = pd.read_csv(tmp_path / "served" / "signals.csv")
    fmu_gate = ref_signals[GATE].astype(bool).tolist()
    assert ref_signals["controller.reject"].astype(bool).tolist() == fmu_gate
    assert seen["commands"] == fmu_gate == served_signals[GATE].astype(bool).tolist()
    assert any(fmu_gate) and seen["events"] >= 1

    # the same run: the rejected fish, the KPIs, every table of the run, bit for bit
    served = tmp_path / "served" / "run" / "runs" / "reject_doubles"
    fmu = tmp_path / "ref" / "run" / "runs" / "reject_doubles"
    rejections = pd.read_csv(served / "rejections.csv")
    pd.testing.assert_frame_equal(rejections, pd.read_csv(fmu / "rejections.csv"), check_exact=True)
    assert len(rejections) >= 1 and set(rejections["device_id"]) == {"gate"}
    kpis = json.loads((tmp_path / "served" / "kpis.json").read_text())
    ref_kpis = json.loads((tmp_path / "ref" / "kpis.json").read_text())
    assert {k: kpis[k] for k in KPI_KEYS} == {k: ref_kpis[k] for k in KPI_KEYS}
    assert kpis["rejected"] >= 1 and kpis["rejected_by"] == ref_kpis["rejected_by"]
    for table in ("tracks", "photoeyes", "belts", "fish", "detections"):
        pd.testing.assert_frame_equal(pd.read_csv(served / f"{table}.csv"), pd.read_csv(fmu / f"{table}.csv"),
                                      check_exact=True)
    info = json.loads((tmp_path / "served" / "run_info.json").read_text())
    assert info["status"] == "ok" and info["served"]["mode"] == "lockstep"
    assert info["served"]["external_inputs"] == [GATE]
    # every change the PLC wrote, taken at the start of the step it was written for: the FMU's reject edges
    edges = [round(0.01 * i, 9) for i, (a, b) in enumerate(zip([False, *fmu_gate], fmu_gate)) if a != b]
    assert [w["t_s"] for w in info["served"]["writes"]] == edges
