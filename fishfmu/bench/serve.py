"""How well ``fishfmu serve --realtime`` keeps to the wall clock on this machine.

    fishfmu bench serve                               # paper test (controller FMU inside) and over OPC UA
    fishfmu bench serve --continuous-s 120            # also the first 120 s of the continuous line, both ways
    fishfmu bench serve --set plant.numerics.threads=2   # every case with Exudyn on two threads

Each case serves a scenario in a subprocess at real time x ``factor`` on a free loopback port and reads the
lateness the server measured (``run_info.json``, ``served.pacing``: each step's start against its due time,
p50/p99/max and overruns, a step starting more than one communication step late).  The paper test runs
twice: as shipped (the controller FMU steps inside the server, a passive client polls the photo-eyes every
10 ms) and as ``paper_opcua.toml``, where a PLC stand-in in its own process writes the four setpoints every
10 ms over OPC UA (the controller's fixed profile); the continuous line the same two ways (``continuous.toml``,
``continuous_opcua.toml``).  Results go to ``bench-results/serve_bench.json``.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fishfmu.session import Interrupted, stop_between_steps

ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def plc(url: str, speeds: list[float] | None, startup_delay_s: float = 1.0, scan_s: float = 0.01,
              stop: Any = None) -> int:
    """A PLC stand-in: every ``scan_s`` of wall time read the time and the photo-eyes, and (``speeds``) write the
    controller's fixed profile as setpoints, until the run ends or ``stop`` (a
    :class:`fishfmu.cosim.stop.StopRequest`) is requested; returns the scans made."""
    stopped = lambda: stop is not None and stop.requested  # noqa: E731
    from asyncua import Client, ua  # slow and optional: the OPC UA client, only while a case runs
    logging.getLogger("asyncua").setLevel(logging.ERROR)  # session-timeout notices on every connect
    deadline = time.monotonic() + 120.0
    while True:
        client = Client(url)
        try:
            await client.connect()
            break
        except (OSError, asyncio.TimeoutError):
            if time.monotonic() > deadline or stopped():
                raise
            await asyncio.sleep(0.2)
    scans = 0
    try:
        idx = await client.get_namespace_index("urn:fishfmu")
        node = lambda name: client.get_node(ua.NodeId(name, idx))  # noqa: E731
        t_node, state = node("fishfmu.time_s"), node("fishfmu.run_state")
        eyes = [node(f"plant.pe_c{i}.blocked") for i in range(1, 5)]
        setpoints = [node(f"drive_c{i}.speed_setpoint") for i in range(1, 5)] if speeds else []
        n = len(speeds or [])
        while not stopped() and await state.read_value() == "running":
            t = await t_node.read_value()
            for eye in eyes:
                await eye.read_value()
            for i, sp in enumerate(setpoints, start=1):
                on = t >= (n - i) * startup_delay_s - 1e-9
                await sp.write_value(ua.Variant(speeds[i - 1] if on else 0.0, ua.VariantType.Double))
            scans += 1
            await asyncio.sleep(scan_s)
    except (ua.UaError, OSError, asyncio.TimeoutError):
        pass  # the server stopped between two reads: the run is over
    finally:
        # the server may be gone already (its run ended, or a Ctrl-C reached it first): asyncua then logs the failed
        # close_session with a traceback before going on, which is no failure of the benchmark
        quiet = logging.getLogger("asyncua")
        level = quiet.level
        quiet.setLevel(logging.CRITICAL)
        try:
            await client.disconnect()
        except Exception:  # noqa: BLE001 - the same, raised instead of logged
            pass
        finally:
            quiet.setLevel(level)
    return scans


def serve_case(scenario: Path, factor: float, overrides: list[str], speeds: list[float] | None) -> dict[str, Any]:
    url = f"opc.tcp://127.0.0.1:{_free_port()}"
    with tempfile.TemporaryDirectory(prefix="fishfmu-serve-bench-") as tmp:
        out = Path(tmp) / "out"
        cmd = [sys.executable, "-m", "fishfmu.cli", "serve", str(scenario), "--endpoint", url, "--realtime",
               str(factor), "--out", str(out), "--no-report", "--grace", "0", "--allow-anonymous-write",
               *overrides]  # ends with its run; its PLC writes without logging in
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        # a signal only asks the PLC stand-in to stop at its next scan: raised inside asyncio's event loop it would
        # be caught and logged there with a traceback
        with stop_between_steps() as stop:
            try:
                scans = asyncio.run(plc(url, speeds, stop=stop))
            except (OSError, asyncio.TimeoutError):
                if not stop.requested:
                    raise
        if stop.requested:  # the served case is stopped too (a Ctrl-C to the group reached it already)
            if proc.poll() is None:
                proc.send_signal(stop.signum)
            proc.communicate(timeout=60)
            raise Interrupted(stop.signum)
        stdout, stderr = proc.communicate(timeout=3600)
        wall = time.perf_counter() - t0
        if proc.returncode not in (0, 1):
            raise RuntimeError(f"serve failed ({proc.returncode}): {stderr.strip()[-500:]}")
        info = json.loads((out / "run_info.json").read_text())
        kpis = json.loads((out / "kpis.json").read_text())
    return {"scenario": scenario.name, "overrides": overrides, "factor": factor, "client": "PLC writing setpoints"
            if speeds else "passive reader", "client_scans": scans, "t_end_s": info["t_end_s"],
            "wall_s": round(wall, 2), "pacing": info["served"]["pacing"], "behind": info["served"].get("behind"),
            "fish_in": kpis.get("fish_in"), "singulation_rate": kpis.get("singulation_rate")}


SCENARIOS = tuple(ROOT / "scenarios" / f"{name}.toml" for name in ("paper_dump", "paper_opcua", "continuous",
                                                                    "continuous_opcua"))
"""The scenarios served, in order (the continuous ones only with ``continuous_s``)."""


def bench(factor: float = 1.0, continuous_s: float | None = None, sets: list[str] | None = None,
          on_case: Callable[[dict], None] | None = None) -> dict[str, Any]:
    """Serve each case (``sets``: ``KEY=VALUE`` overrides for every one, as ``--set`` takes them); ``on_case(case)``
    after each (an interrupted benchmark keeps what it measured)."""
    extra = [a for s in sets or [] for a in ("--set", s)]
    paper_dump, paper_opcua, continuous, continuous_opcua = SCENARIOS
    plan = [(paper_dump, extra, None), (paper_opcua, extra, [0.25, 0.50, 0.80, 1.25])]
    if continuous_s:
        duration = ["--set", f"run.duration_s={continuous_s:g}", *extra]
        plan += [(continuous, duration, None), (continuous_opcua, duration, [0.50, 0.80, 1.25, 1.60])]
    cases = []
    for scenario, overrides, speeds in plan:
        cases.append(serve_case(scenario, factor, overrides, speeds))
        if on_case is not None:
            on_case(cases[-1])
    return {"benchmark": "serve", "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                                              "python": platform.python_version()},
            "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "cases": cases}


def summary(doc: dict[str, Any]) -> list[str]:
    lines = []
    for c in doc["cases"]:
        p = c["pacing"]
        lines.append(f"{c['scenario']} {' '.join(c['overrides'])} x{c['factor']:g} ({c['client']}): "
                     f"{p['steps']} steps to t = {c['t_end_s']:g} s in {c['wall_s']:g} s; lateness p50 "
                     f"{1e3 * p['lateness_p50_s']:.2f} ms, p99 {1e3 * p['lateness_p99_s']:.2f} ms, max "
                     f"{1e3 * p['lateness_max_s']:.1f} ms; {p['overruns']} overruns"
                     + (f"; {c['behind']}" if c["behind"] else ""))
    return lines
