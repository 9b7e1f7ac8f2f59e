"""The served line's information model (issue 42): an object per component, descriptions, units and ranges where
standard OPC UA clients look, states of Booleans and codes, parameters from the line table, only the inputs
writable, BuildInfo naming fishfmu; and the same model as the signal list (``fishfmu signal-list``).

The client is node-opcua (another OPC UA stack, tests/opcua_model_client.js) and its own helper
``readUAAnalogItem``; the expected values come from the scenario file and the FMUs' model descriptions read here,
not from fishfmu's model.
"""

from __future__ import annotations

import asyncio
import csv
import io
import json
import os
import shutil
import subprocess
import sys
import tomllib
from importlib.metadata import version
from pathlib import Path

import pytest

pytest.importorskip("asyncua")

from tests.test_plc_reject import GATE, served_variant  # noqa: E402
from tests.test_serve import NODE_OPCUA, connect, free_port  # noqa: E402

ROOT = Path(__file__).parents[1]
SCENARIO = ROOT / "scenarios" / "reject_doubles.toml"
SHORT = ["--set", "fish.count=2", "--set", "run.duration_s=2", "--no-report"]
MTR = (ord("M") << 16) | (ord("T") << 8) | ord("R")  # OPC UA Part 8: the UNECE code's characters, big-endian
NEW = (ord("N") << 16) | (ord("E") << 8) | ord("W")


def _line() -> dict:
    return tomllib.loads(SCENARIO.read_text())["line"]


def _signal_list(tmp_path: Path, scenario: Path) -> list[dict[str, str]]:
    out = tmp_path / "signals.csv"
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "signal-list", str(scenario), "--out", str(out),
                          "--set", "fish.count=2"], capture_output=True, text=True, timeout=120)
    assert cli.returncode == 0, cli.stderr
    return list(csv.DictReader(io.StringIO(out.read_text())))


async def _listening(url: str, proc: subprocess.Popen) -> None:
    await (await connect(url, proc)).disconnect()


def users_file(tmp_path: Path, users: dict[str, tuple[str, str]]) -> Path:
    """A --users file of ``{name: (role, password)}``, the passwords hashed by `fishfmu hash-password`."""
    lines = []
    for name, (role, password) in users.items():
        hashed = subprocess.run([sys.executable, "-m", "fishfmu.cli", "hash-password"], input=password + "\n",
                                capture_output=True, text=True, timeout=60)
        assert hashed.returncode == 0 and password not in hashed.stdout, hashed.stderr
        lines += ["[[user]]", f'name = "{name}"', f'role = "{role}"', f'password = "{hashed.stdout.strip()}"', ""]
    path = tmp_path / "users.toml"
    path.write_text("\n".join(lines))
    return path


def _node_opcua(tmp_path: Path, scenario: Path) -> dict:
    if not (NODE_OPCUA / "node-opcua-client").is_dir() or shutil.which("node") is None:
        if os.environ.get("CI") == "true":
            pytest.fail(".ci/run installs node-opcua-client into .ci/node-opcua; it is missing")
        pytest.skip("node-opcua-client not installed (.ci/run installs it)")
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "fishfmu.cli", "serve", str(scenario), "--endpoint", url, "--out",
                             str(tmp_path / "served"), *SHORT, "--users",
                             str(users_file(tmp_path, {"plc": ("operator", "s3cret pass")}))],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    asyncio.run(_listening(url, proc))  # the line is built and served before node-opcua's retries run out
    env = {**os.environ, "NODE_PATH": str(NODE_OPCUA), "HOME": str(tmp_path)}
    js = subprocess.run(["node", str(Path(__file__).parent / "opcua_model_client.js"), url, "plc", "s3cret pass"],
                        capture_output=True, text=True, env=env, timeout=180)
    proc.communicate(timeout=300)
    assert js.returncode == 0, js.stderr
    return json.loads(next(line for line in js.stdout.splitlines() if line.startswith("RESULT "))[7:])


def test_node_opcua_finds_objects_units_ranges_states_and_parameters(tmp_path):
    scenario = served_variant(tmp_path)
    seen = _node_opcua(tmp_path, scenario)
    line = _line()
    cam = line["cameras"][0]
    gate = line["devices"][0]
    objects = set(seen["objects"])
    # an object per conveyor, photo-eye, camera, device and FMU instance
    assert {f"Objects/fishfmu/plant/{c['id']}" for c in line["conveyors"]} <= objects
    assert {f"Objects/fishfmu/plant/{p['id']}" for p in line["photoeyes"]} <= objects
    assert {f"Objects/fishfmu/plant/{cam['id']}", f"Objects/fishfmu/plant/{gate['id']}"} <= objects
    fmus = [f["name"] for f in tomllib.loads(scenario.read_text())["fmu"]]
    assert {f"Objects/fishfmu/{n}" for n in fmus} <= objects
    leaves = {leaf["path"]: leaf for leaf in seen["leaves"]}
    # the camera's position, latency and the gate's position and stroke: parameters a PLC computes with
    assert {"Objects/fishfmu/plant/cam/latency_s", "Objects/fishfmu/plant/gate/stroke_s",
            "Objects/fishfmu/plant/gate/x_m", "Objects/fishfmu/plant/cam/x_start_m"} <= set(leaves)
    # node-opcua's standard helper finds units and ranges: the camera's range is its field of view
    lead_x = seen["analog"]["plant.cam.lead_x"]
    assert lead_x["unit"] == "m" and lead_x["unitId"] == MTR
    assert lead_x["namespaceUri"] == "http://www.opcfoundation.org/UA/units/un/cefact"
    assert lead_x["range"] == [cam["x_start_m"], cam["x_end_m"]]
    assert seen["analog"]["plant.c4.load_force"]["unitId"] == NEW and seen["analog"]["plant.c4.load_force"]["range"] is None
    assert seen["analog"]["drive_c4.speed_setpoint"]["unit"] == "m/s"
    # types where clients look: AnalogItemType (i=2368), TwoStateDiscreteType (2373), MultiStateValueDiscrete (11238)
    assert leaves["Objects/fishfmu/plant/cam/lead_x"]["typeDefinition"] == "ns=0;i=2368"
    assert leaves["Objects/fishfmu/plant/pe_c4/blocked"]["typeDefinition"] == "ns=0;i=2373"
    assert leaves["Objects/fishfmu/plant/cam/lead_heading"]["typeDefinition"] == "ns=0;i=11238"
    assert seen["twoStates"] == ["blocked", "clear"]
    assert seen["enumValues"] == [[-1, "tail first"], [0, "no fish"], [1, "head first"]]
    assert seen["asText"] == "no fish"  # no fish in view at the start
    # descriptions from the ports table and the FMU's modelDescription, and which twin a PLC reads
    assert leaves["Objects/fishfmu/plant/pe_c4/blocked"]["description"].startswith("A fish cuts the beam")
    twin = leaves["Objects/fishfmu/controller/cam_lead_x"]["description"]
    assert "fed from plant.cam.lead_x" in twin and "one step older" in twin
    # only the scenario's inputs are writable
    assert [p for p, leaf in leaves.items() if leaf.get("writable")] == ["Objects/fishfmu/plant/gate/command"]
    assert not any(leaf.get("userWritable") for leaf in leaves.values())  # to this anonymous session: none
    assert GATE == "plant.gate.command"
    # secure by default: an anonymous client reads but may not write nor call; a user with a role may
    assert seen["anonymous"] == {"write": "BadUserAccessDenied", "stop": "BadUserAccessDenied"}
    assert seen["byUser"] == {"userWritable": True, "write": "Good", "stop": "Good"}  # the operator's own rights
    assert seen["build"] == {"productName": "fishfmu serve", "manufacturerName": "fishfmu",
                             "softwareVersion": version("fishfmu")}
    # the signal list is what the server serves: the same node ids, the same writable ones
    rows = _signal_list(tmp_path, scenario)
    served = {leaf["nodeId"].split(";s=", 1)[1] for leaf in seen["leaves"]}
    assert {r["node_id"].split(";s=", 1)[1] for r in rows} == served
    assert {r["node_id"] for r in rows if r["access"] == "read-write"} == {f"nsu=urn:fishfmu;s={GATE}"}
    by_path = {r["browse_path"]: r for r in rows}
    assert set(by_path) == set(leaves)


def test_the_signal_list_gives_each_signal_its_address_type_unit_range_and_direction(tmp_path):
    rows = {r["node_id"].split(";s=", 1)[1]: r for r in _signal_list(tmp_path, SCENARIO)}
    line = _line()
    cam, gate = line["cameras"][0], line["devices"][0]
    lead_x = rows["plant.cam.lead_x"]
    assert (lead_x["data_type"], lead_x["unit"], lead_x["unece_code"], lead_x["direction"]) == ("Double", "m", "MTR",
                                                                                              "out")
    assert (float(lead_x["range_low"]), float(lead_x["range_high"])) == (cam["x_start_m"], cam["x_end_m"])
    assert rows["plant.cam.latency_s"]["value"] == str(cam["latency_s"])
    assert rows["plant.gate.stroke_s"]["value"] == str(gate["stroke_s"])
    assert rows["plant.gate.stroke_s"]["direction"] == "parameter" and rows["plant.gate.stroke_s"]["unit"] == "s"
    assert rows["plant.pe_c4.blocked"]["states"] == "true=blocked; false=clear"
    assert rows["plant.cam.lead_heading"]["states"] == "-1=tail first; 0=no fish; 1=head first"
    # reject_doubles.toml runs with its controller FMU: no client writes anything
    assert not [k for k, r in rows.items() if r["access"] == "read-write"]
    assert rows["fishfmu.step"]["direction"] == "method"


def test_the_signal_list_never_writes_over_a_file_fishfmu_did_not_write(tmp_path):
    mine = tmp_path / "tags.csv"
    mine.write_text("my tag table\n")
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "signal-list", str(SCENARIO), "--out", str(mine)],
                         capture_output=True, text=True, timeout=120)
    assert cli.returncode == 2 and "tags.csv" in cli.stderr and len(cli.stderr.strip().splitlines()) == 1
    assert mine.read_text() == "my tag table\n"
