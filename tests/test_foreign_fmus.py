"""FMUs that fishfmu's builder did not make (pythonfmu exports of the models in ``tests/fmu_models``) in the
paper's line: connections with a gain, conversions between types, units, recording any variable, bounds on
signals, setpoints by declaration and the stepping order (issue 17).

Expected values are worked out from the models (a counter, a pass-through, a first-order lag, an oscillator)
or taken from fmpy's own ``simulate_fmu`` of the same FMU, not from fishfmu's output.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tomli_w

pytest.importorskip("pythonfmu")
pytest.importorskip("pythonfmu3")

from plant.errors import InputError  # noqa: E402

from fishfmu.cosim.build import check_scenario  # noqa: E402
from fishfmu.cosim.runner import run_scenario  # noqa: E402
from fishfmu.scenario.schema import load_scenario  # noqa: E402

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
MODELS = Path(__file__).parent / "fmu_models"


@pytest.fixture(scope="module")
def fmus(tmp_path_factory) -> dict[str, Path]:
    """Each model of tests/fmu_models exported by pythonfmu (FMI 2.0) or pythonfmu3 (FMI 3.0, the ``*3`` ones)."""
    from pythonfmu.builder import FmuBuilder
    from pythonfmu3 import FmuBuilder as Fmu3Builder
    out = tmp_path_factory.mktemp("pythonfmu")
    built = {name: Path(FmuBuilder.build_FMU(MODELS / f"{name}.py", dest=out))
             for name in ("counter", "passthrough", "first_order", "oscillator")}
    built.update({name: Path(Fmu3Builder.build_FMU(MODELS / f"{name}.py", dest=out)) for name in ("counter3", "shaft3")})
    return built


def scenario(tmp_path: Path, fmus: dict[str, Path], add: dict[str, str], drop: tuple[str, ...] = (),
             **tables) -> Path:
    """The paper's scenario, 3 s and 2 fish, with the FMUs ``add`` (instance name -> model), the string
    connections to the targets ``drop`` removed, and ``tables`` merged in at the top level."""
    doc = tomllib.loads(PAPER.read_text())
    doc["run"].update(duration_s=3.0, stop_when_clear=False)
    doc["fish"]["count"] = 2
    doc["expect"] = {}
    doc["fmu"] += [{"name": n, "path": str(fmus[m])} for n, m in add.items()]
    doc["wiring"]["connections"] = [c for c in doc["wiring"]["connections"]
                                    if c.split("->")[1].strip() not in drop]
    for key, value in tables.items():
        if isinstance(value, dict) and isinstance(doc.get(key), dict):
            doc[key].update(value)
        else:
            doc[key] = value
    path = tmp_path / "scenario.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


def run(path: Path):
    result = run_scenario(load_scenario(path), path)
    assert result.status == "ok", result.error
    return result


def test_an_integer_counter_drives_a_real_setpoint_through_a_gain(tmp_path, fmus):
    # Stair-like counter, one up every 0.5 s, x 0.1 -> the drive's setpoint in m/s: 0.1 per half second
    path = scenario(tmp_path, fmus, {"stair": "counter"}, drop=("drive_c1.speed_setpoint",),
                    wiring={"connection": [{"from": "stair.counter", "to": "drive_c1.speed_setpoint", "gain": 0.1}]})
    doc = tomllib.loads(path.read_text())
    doc["fmu"][-1]["parameters"] = {"period_s": 0.5}
    path.write_text(tomli_w.dumps(doc))
    result = run(path)
    s = result.signals
    assert s["stair.counter"].dtype.kind == "i"
    # the counter after its step at t, sent the same step (it steps before the drive it feeds)
    assert s["stair.counter"].to_numpy() == pytest.approx(np.floor(s["t_s"].to_numpy() / 0.5 + 1e-9))
    assert s["drive_c1.speed_setpoint"].to_numpy() == pytest.approx(0.1 * s["stair.counter"].to_numpy())
    # belts.csv logs what the drive was sent as c1's setpoint: at 2.5 s the counter is 5, 0.5 m/s
    belts = result.run.belts
    c1 = belts[belts["conveyor_id"] == "c1"].set_index("t_s")["setpoint_mps"]
    assert c1.loc[2.5] == pytest.approx(0.5)
    assert result.wiring["setpoints"]["c1"] == "drive_c1.speed_setpoint"
    assert {"connection": "stair.counter -> drive_c1.speed_setpoint", "from": "Integer [-]", "to": "Real [m/s]",
            "gain": 0.1, "offset": None, "round": False} in result.wiring["conversions"]


def test_a_boolean_beam_widens_to_real_and_a_real_narrows_to_integer_only_when_rounded(tmp_path, fmus):
    conns = [{"from": "plant.pe_c1.blocked", "to": "pass.real_in"},
             {"from": "plant.c1.load_force", "to": "pass.int_in"}]
    path = scenario(tmp_path, fmus, {"pass": "passthrough"}, wiring={"connection": conns})
    with pytest.raises(InputError, match=r"wiring\.connection\[1\].*'plant\.c1\.load_force' is Real but "
                                         r"'pass\.int_in' is Integer: a narrowing conversion, refused unless"):
        check_scenario(load_scenario(path), path)
    conns[1]["round"] = True
    path = scenario(tmp_path, fmus, {"pass": "passthrough"}, wiring={"connection": conns},
                    record={"variables": ["pass.*_out"]})
    s = run(path).signals
    # the beam as 0.0 / 1.0, the load force (of the step before: FMUs step before the plant) rounded to whole
    # newtons; what goes into the pass-through at a step comes out at its end
    assert set(s["pass.real_in"].unique()) <= {0.0, 1.0}
    assert s["pass.real_out"].to_numpy() == pytest.approx(s["pass.real_in"].to_numpy())
    assert s["pass.int_in"].to_numpy() == pytest.approx(np.round(s["plant.c1.load_force"].shift(1).fillna(0.0)))
    assert (s["pass.int_out"] == s["pass.int_in"]).all()
    # no conversion from a String to a number
    bad = scenario(tmp_path, fmus, {"pass": "passthrough"},
                   wiring={"connection": [{"from": "pass.str_out", "to": "pass.real_in"}]})
    with pytest.raises(InputError, match="'pass.str_out' is String but 'pass.real_in' is Real: no conversion"):
        check_scenario(load_scenario(bad), bad)


def test_different_units_are_refused_unless_a_gain_states_the_conversion(tmp_path, fmus):
    # the drive's motor speed is in rpm, the plant's belt speed in m/s
    path = scenario(tmp_path, fmus, {}, drop=("plant.c1.speed",),
                    wiring={"connection": [{"from": "drive_c1.motor_speed", "to": "plant.c1.speed"}]})
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "check", str(path)], capture_output=True, text=True)
    assert cli.returncode == 2
    assert "'drive_c1.motor_speed' is in rpm but 'plant.c1.speed' in m/s" in cli.stderr
    assert "wiring.connection[0]" in cli.stderr and len(cli.stderr.strip().splitlines()) == 1
    doc = tomllib.loads(path.read_text())
    doc["wiring"]["connection"][0]["gain"] = 0.0005
    path.write_text(tomli_w.dumps(doc))
    check_scenario(load_scenario(path), path)


def test_recorded_states_equal_fmpys_own_simulation_of_the_same_fmu(tmp_path, fmus):
    from fmpy import simulate_fmu
    path = scenario(tmp_path, fmus, {"vdp": "oscillator", "lag": "first_order"},
                    wiring={"inputs": {"lag.u": 1.0}}, record={"variables": ["vdp.*", "lag.x"]})
    doc = tomllib.loads(path.read_text())
    doc["fmu"][-2]["step_multiple"] = 5  # the oscillator steps every 0.05 s, the lag every 0.01 s
    path.write_text(tomli_w.dumps(doc))
    s = run(path).signals
    s = s.set_index(np.round(s["t_s"].to_numpy(), 6))
    ref = simulate_fmu(str(fmus["oscillator"]), stop_time=3.0, step_size=0.05, output_interval=0.05,
                       output=["x", "v"])
    got = s.loc[np.round(ref["time"][1:] - 0.04, 6)]  # its step from t - 0.05 is recorded at t - 0.04 (and held)
    assert got["vdp.x"].to_numpy() == pytest.approx(ref["x"][1:], abs=1e-12)
    assert got["vdp.v"].to_numpy() == pytest.approx(ref["v"][1:], abs=1e-12)
    assert "vdp.mu" in s  # a parameter matched by the wildcard is recorded too
    # the lag from its start value 0.5 towards u = 1 with tau = 0.4 s: x(t) = 1 - 0.5 exp(-t / 0.4)
    t = s["t_s"].to_numpy()
    assert s["lag.x"].to_numpy() == pytest.approx(1.0 - 0.5 * np.exp(-t / 0.4), rel=1e-9)


def test_bounds_on_recorded_signals(tmp_path, fmus):
    path = scenario(tmp_path, fmus, {"lag": "first_order"}, wiring={"inputs": {"lag.u": 1.0}},
                    record={"variables": ["lag.x"]},
                    expect={"lag.x": {"min": 0.6, "max": 1.0, "final": 1.0, "tolerance": 0.001},
                            "drive_c4.belt_speed": {"max": 1.3}})
    result = run_scenario(load_scenario(path), path)
    by = {e.kpi: e for e in result.expect}
    # x starts at 0.5 (below 0.6), stays below 1, ends at 1 - 0.5 exp(-7.5) = 0.99972 (within 0.001 of 1)
    assert not by["lag.x (lowest)"].ok and by["lag.x (lowest)"].value == pytest.approx(1 - 0.5 * math.exp(-0.025))
    assert by["lag.x (highest)"].ok and by["lag.x (final)"].ok
    assert by["lag.x (final)"].value == pytest.approx(1 - 0.5 * math.exp(-3.0 / 0.4))
    assert by["drive_c4.belt_speed (highest)"].ok  # the outfeed runs at 1.25 m/s
    assert not result.expect_ok
    unknown = scenario(tmp_path, fmus, {}, expect={"drive_c1.motor_sped": {"max": 1.0}})
    with pytest.raises(InputError, match=r"expect\.drive_c1\.motor_sped.*not a recorded signal"):
        check_scenario(load_scenario(unknown), unknown)


def test_a_setpoint_is_declared_or_derived_never_guessed_from_a_name(tmp_path, fmus):
    # a vendor "drive" (the pass-through) commanded on real_in: its belt speed is not logged as the setpoint
    conns = [{"from": "controller.setpoint_1", "to": "pass.real_in"}, {"from": "pass.real_out", "to": "plant.c1.speed"}]
    path = scenario(tmp_path, fmus, {"pass": "passthrough"}, drop=("plant.c1.speed", "drive_c1.speed_setpoint"),
                    wiring={"connection": conns})
    result = run(path)
    assert result.wiring["setpoints"]["c1"] == "pass.real_in"
    belts = result.run.belts
    c1 = belts[belts["conveyor_id"] == "c1"].set_index("t_s")
    assert c1["setpoint_mps"].loc[2.5] == pytest.approx(result.signals.set_index("t_s")["pass.real_in"].loc[2.5])
    # commanded twice (a speed and a count): which one is the setpoint must be said
    conns.append({"from": "controller.setpoint_2", "to": "pass.int_in", "round": True})
    path = scenario(tmp_path, fmus, {"pass": "passthrough"}, drop=("plant.c1.speed", "drive_c1.speed_setpoint"),
                    wiring={"connection": conns})
    with pytest.raises(InputError, match=r"its drive 'pass' is commanded by pass\.real_in, pass\.int_in: name one as "
                                         r"\[wiring\] setpoints\.c1"):
        check_scenario(load_scenario(path), path)
    path = scenario(tmp_path, fmus, {"pass": "passthrough"}, drop=("plant.c1.speed", "drive_c1.speed_setpoint"),
                    wiring={"connection": conns, "setpoints": {"c1": "pass.real_in"}})
    check_scenario(load_scenario(path), path)


def test_check_lists_the_stepping_order_and_every_delayed_link(tmp_path, fmus):
    # the counter listed after the drive it feeds still steps first, and drive_c1 (no longer fed by the controller)
    # before the controller, which so reads its speed at once; the other drives' speeds reach it one step late
    path = scenario(tmp_path, fmus, {"stair": "counter"}, drop=("drive_c1.speed_setpoint",),
                    wiring={"connection": [{"from": "stair.counter", "to": "drive_c1.speed_setpoint", "gain": 0.1}]})
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "check", str(path), "--json"], capture_output=True,
                         text=True)
    assert cli.returncode == 0, cli.stderr
    doc = json.loads(cli.stdout)
    order = doc["stepping_order"]
    assert order.index("stair") < order.index("drive_c1") and order[-1] == "plant"
    late = {d["connection"]: d["why"] for d in doc["delayed_links"]}
    assert "feedback" in late["drive_c2.belt_speed -> controller.belt_speed_2"]
    assert "drive_c1.belt_speed -> controller.belt_speed_1" not in late
    assert "plant output" in late["plant.pe_c1.blocked -> controller.pe_1"]
    assert "stair.counter -> drive_c1.speed_setpoint" not in late
    assert doc["fmus"]["stair"]["fmi"] == "2.0"
    out = tmp_path / "out"
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "run", str(path), "--out", str(out), "--no-report"],
                         capture_output=True, text=True)
    assert cli.returncode == 0, cli.stderr
    info = json.loads((out / "run_info.json").read_text())
    assert info["wiring"]["stepping_order"] == order
    assert len(info["wiring"]["delayed_links"]) == len(doc["delayed_links"])
    assert pd.read_csv(out / "signals.csv")["drive_c1.speed_setpoint"].max() == pytest.approx(0.3)


def test_a_state_takes_its_start_value_and_a_computed_output_refuses_one(tmp_path, fmus):
    # x is declared initial = exact: started at 0.8 instead of 0.5, x(t) = 1 - 0.2 exp(-t / 0.4)
    path = scenario(tmp_path, fmus, {"lag": "first_order"}, wiring={"inputs": {"lag.u": 1.0}},
                    record={"variables": ["lag.x"]})
    doc = tomllib.loads(path.read_text())
    doc["fmu"][-1]["parameters"] = {"x": 0.8, "tau": 0.2}
    path.write_text(tomli_w.dumps(doc))
    s = run(path).signals
    assert s["lag.x"].to_numpy() == pytest.approx(1.0 - 0.2 * np.exp(-s["t_s"].to_numpy() / 0.2), rel=1e-9)
    # the pass-through's outputs are computed (initial = calculated): no start value
    path = scenario(tmp_path, fmus, {"pass": "passthrough"})
    doc = tomllib.loads(path.read_text())
    doc["fmu"][-1]["parameters"] = {"real_out": 1.0}
    path.write_text(tomli_w.dumps(doc))
    with pytest.raises(InputError, match=r"fmu\[5\]\.parameters\.real_out.*an output computed by the FMU "
                                         r"\(initial = calculated\): FMI lets no start value be given to it"):
        check_scenario(load_scenario(path), path)


@pytest.mark.parametrize("process", ["in-process", "worker"])
def test_an_fmi3_int32_counter_drives_the_setpoint_in_process_and_in_a_worker(tmp_path, fmus, process):
    path = scenario(tmp_path, fmus, {"stair": "counter3"}, drop=("drive_c1.speed_setpoint",),
                    run={"fmu_process": process}, record={"variables": ["stair.double"]},
                    wiring={"connection": [{"from": "stair.counter", "to": "drive_c1.speed_setpoint", "gain": 0.1}]})
    s = run(path).signals
    t = s["t_s"].to_numpy()
    assert s["stair.counter"].to_numpy() == pytest.approx(np.floor(t + 1e-9))  # one up every second
    assert s["stair.double"].to_numpy() == pytest.approx(2 * np.floor(t + 1e-9))  # a UInt64, recorded
    assert s["drive_c1.speed_setpoint"].to_numpy() == pytest.approx(0.1 * np.floor(t + 1e-9))


def test_an_fmi3_unit_declared_through_a_type_is_checked_and_its_state_matches_fmpy(tmp_path, fmus):
    from fmpy import simulate_fmu
    # shaft3.speed is an AngularVelocity, a type in rpm: not the plant's m/s
    path = scenario(tmp_path, fmus, {"shaft": "shaft3"}, drop=("plant.c1.speed",),
                    wiring={"connection": [{"from": "shaft.speed", "to": "plant.c1.speed"}]})
    with pytest.raises(InputError, match="'shaft.speed' is in rpm but 'plant.c1.speed' in m/s"):
        check_scenario(load_scenario(path), path)
    # a drum of 0.1 m radius: 1 rpm = 2 pi 0.1 / 60 m/s; the shaft from 100 rpm towards 1000 rpm
    path = scenario(tmp_path, fmus, {"shaft": "shaft3"}, drop=("plant.c1.speed",),
                    wiring={"connection": [{"from": "shaft.speed", "to": "plant.c1.speed",
                                            "gain": 2 * math.pi * 0.1 / 60}], "inputs": {"shaft.u": 1000.0}})
    s = run(path).signals
    ref = simulate_fmu(str(fmus["shaft3"]), stop_time=3.0, step_size=0.01, output_interval=0.01,
                       start_values={"u": 1000.0}, output=["speed"])
    assert s["shaft.speed"].to_numpy() == pytest.approx(ref["speed"][1:], rel=1e-12)
    # the shaft steps before the plant: the belt runs at its speed of the same step, converted
    assert s["plant.c1.speed"].to_numpy() == pytest.approx(s["shaft.speed"].to_numpy() * 2 * math.pi * 0.1 / 60)


# --- SSP: a system of FMUs with a linear transformation and parameter values, as another tool hands it over ---
# The SSD and SSV below are written to the SSP 1.0 standard by hand (not by fishfmu) and validated on import
# against the standard's schemas; the FMUs inside are pythonfmu's.

SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription version="1.0" name="controls"
    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"
    xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">
  <ssd:System name="controls">
    <ssd:Connectors><ssd:Connector name="level" kind="output"/></ssd:Connectors>
    <ssd:ParameterBindings>
      <ssd:ParameterBinding prefix="stair.">
        <ssd:ParameterValues>
          <ssv:ParameterSet version="1.0" name="system">
            <ssv:Parameters>
              <ssv:Parameter name="period_s"><ssv:Real value="0.5" unit="s"/></ssv:Parameter>
            </ssv:Parameters>
          </ssv:ParameterSet>
        </ssd:ParameterValues>
      </ssd:ParameterBinding>
    </ssd:ParameterBindings>
    <ssd:Elements>
      <ssd:Component name="stair" source="{dir}Counter.fmu" type="application/x-fmu-sharedlibrary">
        <ssd:Connectors><ssd:Connector name="counter" kind="output"><ssc:Integer/></ssd:Connector></ssd:Connectors>
      </ssd:Component>
      <ssd:Component name="lag" source="{dir}FirstOrder.fmu">
        <ssd:Connectors>
          <ssd:Connector name="u" kind="input"><ssc:Real/></ssd:Connector>
          <ssd:Connector name="x" kind="output"><ssc:Real/></ssd:Connector>
        </ssd:Connectors>
        <ssd:ParameterBindings><ssd:ParameterBinding source="{dir}lag.ssv"/></ssd:ParameterBindings>
      </ssd:Component>
    </ssd:Elements>
    <ssd:Connections>
      <ssd:Connection startElement="stair" startConnector="counter" endElement="lag" endConnector="u">
        <ssc:LinearTransformation factor="0.1" offset="0.05"/>
      </ssd:Connection>
      <ssd:Connection startElement="lag" startConnector="x" endConnector="level"/>
    </ssd:Connections>
  </ssd:System>
</ssd:SystemStructureDescription>
"""

SSV = """<?xml version="1.0" encoding="UTF-8"?>
<ssv:ParameterSet version="1.0" name="{name}" xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">
  <ssv:Parameters>{parameters}
  </ssv:Parameters>
</ssv:ParameterSet>
"""


def ssv(name: str, **values: float | tuple[float, str]) -> str:
    rows = []
    for key, v in values.items():
        value, unit = v if isinstance(v, tuple) else (v, None)
        rows.append(f'\n    <ssv:Parameter name="{key}"><ssv:Real value="{value}"'
                    f'{f" unit={chr(34)}{unit}{chr(34)}" if unit else ""}/></ssv:Parameter>')
    return SSV.format(name=name, parameters="".join(rows))


def ssp_archive(folder: Path, fmus: dict[str, Path], ssd: str = SSD) -> Path:
    import zipfile
    path = folder / "controls.ssp"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("SystemStructure.ssd", ssd.format(dir="resources/"))
        zf.write(fmus["counter"], "resources/Counter.fmu")
        zf.write(fmus["first_order"], "resources/FirstOrder.fmu")
        zf.writestr("resources/lag.ssv", ssv("lag", tau=0.2, x=0.0))
    return path


def check_lag_follows_the_counter_through_the_transformation(s: pd.DataFrame) -> None:
    h = 0.01
    # the counter with its period from the system's binding (0.5 s, not its own 1 s)
    assert s["stair.counter"].to_numpy() == pytest.approx(np.floor(s["t_s"].to_numpy() / 0.5 + 1e-9))
    # the connection's LinearTransformation: u = 0.1 counter + 0.05
    assert s["lag.u"].to_numpy() == pytest.approx(0.1 * s["stair.counter"].to_numpy() + 0.05)
    # tau = 0.2 s and x(0) = 0 from lag.ssv (the FMU's own are 0.4 s and 0.5): the exact step of the lag with the
    # input it was sent for that step (the counter steps first)
    x, u = s["lag.x"].to_numpy(), s["lag.u"].to_numpy()
    expected = u + (np.concatenate([[0.0], x[:-1]]) - u) * np.exp(-h / 0.2)
    assert x == pytest.approx(expected, rel=1e-9, abs=1e-12)
    # the lag's output drives belt c1 (unitless into m/s: allowed), and belts.csv logs it as c1's setpoint
    assert s["drive_c1.speed_setpoint"].to_numpy() == pytest.approx(x)


def ssp_scenario(tmp_path: Path, fmus: dict[str, Path], ssp: str) -> Path:
    return scenario(tmp_path, fmus, {}, drop=("drive_c1.speed_setpoint",), system={"ssp": ssp},
                    wiring={"connection": [{"from": "lag.x", "to": "drive_c1.speed_setpoint"}]},
                    record={"variables": ["stair.counter", "lag.u"]})


def test_an_ssp_archive_brings_fmus_connections_with_a_linear_transformation_and_parameter_values(tmp_path, fmus):
    ssp_archive(tmp_path, fmus)
    path = ssp_scenario(tmp_path, fmus, "controls.ssp")
    before = sorted(p.name for p in tmp_path.iterdir())
    result = run(path)
    check_lag_follows_the_counter_through_the_transformation(result.signals)
    assert {"connection": "stair.counter -> lag.u", "from": "Integer [-]", "to": "Real [-]", "gain": 0.1,
            "offset": 0.05, "round": False} in result.wiring["conversions"]
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing unpacked beside the user's files
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "check", str(path), "--json"], capture_output=True,
                         text=True)
    assert json.loads(cli.stdout)["ssp_not_imported"] == ["lag.x -> controls.level"]
    # the resolved scenario keeps [system] ssp and does not repeat what it brought in
    from fishfmu.scenario.schema import resolved_toml
    resolved = tomllib.loads(resolved_toml(load_scenario(path)))
    assert resolved["system"]["ssp"] == str(tmp_path / "controls.ssp")
    assert [f["name"] for f in resolved["fmu"]] == ["controller", "drive_c1", "drive_c2", "drive_c3", "drive_c4"]


def test_a_bare_ssd_names_fmus_and_parameter_files_inside_its_folder(tmp_path, fmus):
    folder = tmp_path / "system"
    (folder / "fmus").mkdir(parents=True)
    (folder / "controls.ssd").write_text(SSD.format(dir="fmus/"))
    for name, fmu in (("Counter.fmu", "counter"), ("FirstOrder.fmu", "first_order")):
        (folder / "fmus" / name).write_bytes(fmus[fmu].read_bytes())
    (folder / "fmus" / "lag.ssv").write_text(ssv("lag", tau=0.2, x=0.0))
    check_lag_follows_the_counter_through_the_transformation(
        run(ssp_scenario(tmp_path, fmus, "system/controls.ssd")).signals)


@pytest.mark.parametrize("change, message", [
    (("<ssc:LinearTransformation factor=\"0.1\" offset=\"0.05\"/>",
      "<ssc:BooleanMappingTransformation><ssc:MapEntry source=\"true\" target=\"false\"/>"
      "</ssc:BooleanMappingTransformation>"), "stair.counter -> controls.lag.u|mapping transformations"),
    (('name="lag" source', 'name="stair" source'), "component 'stair' appears twice"),
    (("</ssd:Elements>", '<ssd:System name="inner"/></ssd:Elements>'), "nested systems are not supported"),
    (('<ssv:Real value="0.5" unit="s"/>', '<ssv:Real value="half"/>'), "'half' is not a valid"),
    (('startConnector="counter" endElement="lag"', 'startConnector="counter" endElement="lga"'),
     "'lga' is not a component"),
    (('startConnector="counter" endElement="lag"', 'startConnectr="counter" endElement="lag"'),
     "does not conform to the SSP 1.0 schema"),
])
def test_a_bad_ssp_is_refused_naming_the_file_and_what_is_wrong(tmp_path, fmus, change, message):
    ssp_archive(tmp_path, fmus, SSD.replace(*change))
    path = ssp_scenario(tmp_path, fmus, "controls.ssp")
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "check", str(path)], capture_output=True, text=True)
    assert cli.returncode == 2, cli.stderr
    lines = cli.stderr.strip().splitlines()
    assert len(lines) == 1 and "controls.ssp" in lines[0], lines
    assert any(m in lines[0] for m in message.split("|")), lines[0]


def test_a_parameter_file_gives_start_values_and_its_units_are_checked(tmp_path, fmus):
    # TOML: the lag's state starts at 0.8, tau 0.2 s; the inline value wins over the file's
    (tmp_path / "lag.toml").write_text("x = 0.8\ntau = 0.3\n")
    path = scenario(tmp_path, fmus, {"lag": "first_order"}, wiring={"inputs": {"lag.u": 1.0}},
                    record={"variables": ["lag.x"]})
    doc = tomllib.loads(path.read_text())
    doc["fmu"][-1].update(parameter_file="lag.toml", parameters={"tau": 0.2})
    path.write_text(tomli_w.dumps(doc))
    s = run(path).signals
    assert s["lag.x"].to_numpy() == pytest.approx(1.0 - 0.2 * np.exp(-s["t_s"].to_numpy() / 0.2), rel=1e-9)
    # SSV with units: the shaft's speed is in rpm; given in rad/s it is refused, in rpm it is taken
    for unit, ok in (("rad/s", False), ("rpm", True)):
        (tmp_path / "shaft.ssv").write_text(ssv("shaft", speed=(500.0, unit), tau=0.5))
        path = scenario(tmp_path, fmus, {"shaft": "shaft3"}, wiring={"inputs": {"shaft.u": 1000.0}},
                        record={"variables": ["shaft.speed"]})
        doc = tomllib.loads(path.read_text())
        doc["fmu"][-1]["parameter_file"] = "shaft.ssv"
        path.write_text(tomli_w.dumps(doc))
        if not ok:
            with pytest.raises(InputError, match=r"fmu\[5\]\.parameters\.speed.*gives 'speed' in rad/s but FMU "
                                                 r"'shaft' has it in rpm"):
                check_scenario(load_scenario(path), path)
            continue
        s = run(path).signals
        t = s["t_s"].to_numpy()
        assert s["shaft.speed"].to_numpy() == pytest.approx(1000.0 - 500.0 * np.exp(-t / 0.5), rel=1e-9)
