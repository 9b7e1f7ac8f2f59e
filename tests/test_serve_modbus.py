"""The served line over Modbus TCP (issue 42), read and stepped by a Modbus master of another implementation
(pyModbusTCP): the register map of the signal list, 32-bit values in two registers high word first (decoded here
with struct, not with fishfmu's code), lockstep through the step-request register, writes refused unless the
lab-bench option opens them."""

from __future__ import annotations

import asyncio
import csv
import io
import json
import struct
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("asyncua")
pyModbusTCP = pytest.importorskip("pyModbusTCP.client")
from asyncua import ua  # noqa: E402

from tests.test_serve import SERVED, connect, free_port  # noqa: E402

SHORT = ["--set", "fish.count=2", "--set", "run.duration_s=20", "--no-report"]
ILLEGAL_FUNCTION, ILLEGAL_ADDRESS = 1, 2  # Modbus exception codes


def _registers(value: float) -> list[int]:
    """A float32 as two registers, high word first (big-endian words and bytes)."""
    high, low = struct.unpack(">HH", struct.pack(">f", value))
    return [high, low]


def _float(words: list[int]) -> float:
    return struct.unpack(">f", struct.pack(">HH", *words))[0]


def _map(tmp_path) -> dict[str, dict[str, str]]:
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "signal-list", str(SERVED), "--set", "fish.count=2"],
                         capture_output=True, text=True, timeout=120)
    assert cli.returncode == 0, cli.stderr
    return {r["node_id"].split(";s=", 1)[1]: r for r in csv.DictReader(io.StringIO(cli.stdout))}


async def _stop(url: str, proc: subprocess.Popen) -> None:
    client = await connect(url, proc)
    idx = await client.get_namespace_index("urn:fishfmu")
    await client.get_node(ua.NodeId("fishfmu", idx)).call_method(ua.QualifiedName("stop", idx))


def _serve(tmp_path, modbus_port: int, *extra: str) -> tuple[subprocess.Popen, str]:
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "fishfmu.cli", "serve", str(SERVED), "--endpoint", url, "--out",
                             str(tmp_path / "o"), "--modbus", f"127.0.0.1:{modbus_port}", *SHORT, *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    asyncio.run(_ready(url, proc))
    return proc, url


async def _ready(url: str, proc: subprocess.Popen) -> None:
    await (await connect(url, proc)).disconnect()


def test_a_modbus_master_writes_a_setpoint_steps_the_line_and_reads_it_back(tmp_path):
    regs = _map(tmp_path)
    setpoint, speed = regs["drive_c4.speed_setpoint"], regs["drive_c4.belt_speed"]
    beam, clock = regs["plant.pe_c4.blocked"], regs["fishfmu.time_s"]
    assert (setpoint["modbus_table"], speed["modbus_table"], beam["modbus_table"]) == (
        "holding_register", "input_register", "discrete_input")
    assert setpoint["modbus_encoding"] == speed["modbus_encoding"] == "float32"
    port = free_port()
    proc, url = _serve(tmp_path, port, "--allow-anonymous-write")
    master = pyModbusTCP.ModbusClient(host="127.0.0.1", port=port, unit_id=1, auto_open=True, timeout=120)
    try:
        assert master.write_multiple_registers(int(setpoint["modbus_address"]), _registers(1.25))
        assert master.read_input_registers(0, 1) == [1]  # running
        assert master.write_single_register(0, 100)  # lockstep: the reply comes after 100 steps
        t = _float(master.read_input_registers(int(clock["modbus_address"]), 2))
        v = _float(master.read_input_registers(int(speed["modbus_address"]), 2))
        blocked = master.read_discrete_inputs(int(beam["modbus_address"]), 1)
        sent = _float(master.read_holding_registers(int(setpoint["modbus_address"]), 2))
        # an output is not written: the master is told so and nothing changes
        refused = master.write_multiple_registers(int(speed["modbus_address"]), _registers(9.0))
        refused_code = master.last_except
    finally:
        master.close()
        asyncio.run(_stop(url, proc))
        proc.communicate(timeout=120)
    assert t == 1.0 and sent == 1.25 and blocked == [False]
    assert refused is False and refused_code == ILLEGAL_ADDRESS
    signals = pd.read_csv(tmp_path / "o" / "signals.csv")
    at_1s = signals.loc[np.isclose(signals["t_s"], 1.0), "drive_c4.belt_speed"].iloc[0]
    assert v == float(np.float32(at_1s)) and 0.5 < v <= 1.25  # the drive ramped toward the setpoint written
    info = json.loads((tmp_path / "o" / "run_info.json").read_text())
    assert info["served"]["writes"] == [{"t_s": 0.0, "input": "drive_c4.speed_setpoint", "value": 1.25}]


def test_modbus_writes_are_refused_without_the_lab_bench_option(tmp_path):
    regs = _map(tmp_path)
    port = free_port()
    proc, url = _serve(tmp_path, port)
    master = pyModbusTCP.ModbusClient(host="127.0.0.1", port=port, unit_id=1, auto_open=True, timeout=60)
    try:
        wrote = master.write_multiple_registers(int(regs["drive_c4.speed_setpoint"]["modbus_address"]),
                                                _registers(1.0))
        code = master.last_except
        stepped = master.write_single_register(0, 1)
        state = master.read_input_registers(0, 1)
    finally:
        master.close()
        proc.terminate()
        proc.communicate(timeout=120)
    assert wrote is False and code == ILLEGAL_FUNCTION and stepped is False and state == [1]


@pytest.mark.parametrize("where", ["127.0.0.1:abc", "127.0.0.1", "10.1.2.3:5020"])
def test_a_modbus_address_the_server_must_not_listen_at_is_bad_input(tmp_path, where):
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "serve", str(SERVED), "--modbus", where, "--out",
                          str(tmp_path / "o"), *SHORT], capture_output=True, text=True, timeout=120)
    assert cli.returncode == 2 and "--modbus" in cli.stderr and len(cli.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
