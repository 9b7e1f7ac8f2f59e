"""``fishfmu export-ssp`` (issue 44): a scenario's system as an SSP 1.0 archive, checked by tools fishfmu did not
write: the SSP standard's XML schemas (the copies fmpy ships), fmpy's SSD reader, libcosim (libcosimpy) loading and
running it; and fishfmu reading it back (``fishfmu run line.ssp``) to the same KPIs and signals, bit for bit."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from lxml import etree

pytest.importorskip("pythonfmu")  # the plant FMU inside the archive is made with it

from fishfmu.cosim.runner import run_scenario  # noqa: E402
from fishfmu.fmu.build import build_fmu, builtin_fmu  # noqa: E402
from fishfmu.scenario.schema import load_scenario  # noqa: E402
from fishfmu.scenario.ssp import NS  # noqa: E402

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "scenarios" / "paper_test.toml"
USER_FMU = ROOT / "scenarios" / "user_fmu.toml"
SHORT = {"fish.count": 4, "run.duration_s": 16.0}
SCHEMAS = Path(fmpy.__file__).parent / "ssp" / "schema"
"""The SSP 1.0 standard's XSDs as fmpy ships them (Modelica Association's files; fmpy validates with them too)."""


def export(scenario: Path, out: Path, *sets: str) -> subprocess.CompletedProcess:
    args = [a for s in sets for a in ("--set", s)]
    return subprocess.run([sys.executable, "-m", "fishfmu.cli", "export-ssp", str(scenario), "--out", str(out), *args],
                          capture_output=True, text=True)


@pytest.fixture(scope="module")
def paper_ssp(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ssp") / "line.ssp"
    cli = export(PAPER, out, *(f"{k}={v}" for k, v in SHORT.items()))
    assert cli.returncode == 0, cli.stderr
    return out


@pytest.fixture(scope="module")
def user_drive(tmp_path_factory) -> Path:
    return build_fmu("conveyor_drive", tmp_path_factory.mktemp("vendor"),
                     {"rated_power": 370.0, "gear_ratio": 10.0, "ramp_acceleration": 0.5})


def _xml(ssp: Path, member: str):
    with zipfile.ZipFile(ssp) as zf:
        return etree.fromstring(zf.read(member))


def test_the_archive_validates_against_the_ssp_schemas_and_says_the_system(paper_ssp):
    ssd_schema = etree.XMLSchema(etree.parse(str(SCHEMAS / "SystemStructureDescription.xsd")))
    ssv_schema = etree.XMLSchema(etree.parse(str(SCHEMAS / "SystemStructureParameterValues.xsd")))
    ssd = _xml(paper_ssp, "SystemStructure.ssd")
    assert ssd_schema.validate(ssd), ssd_schema.error_log
    with zipfile.ZipFile(paper_ssp) as zf:
        ssvs = [n for n in zf.namelist() if n.endswith(".ssv")]
        assert zf.read("resources/conveyor_drive.fmu") == builtin_fmu("conveyor_drive").read_bytes()
    assert sorted(ssvs) == ["resources/controller.ssv", "resources/plant.ssv"]
    for name in ssvs:
        doc = _xml(paper_ssp, name)
        assert ssv_schema.validate(doc), (name, ssv_schema.error_log)
    comps = {c.get("name"): c for c in ssd.iterfind("ssd:System/ssd:Elements/ssd:Component", NS)}
    assert list(comps) == ["controller", "drive_c1", "drive_c2", "drive_c3", "drive_c4", "plant"]
    assert {comps[f"drive_c{i}"].get("source") for i in range(1, 5)} == {"resources/conveyor_drive.fmu"}

    def connector(comp: str, name: str):
        return comps[comp].find(f"ssd:Connectors/ssd:Connector[@name='{name}']", NS)
    assert connector("drive_c1", "belt_speed").get("kind") == "output"
    assert connector("drive_c1", "belt_speed").find("ssc:Real", NS).get("unit") == "m/s"
    assert connector("plant", "c1.speed").get("kind") == "input"
    assert connector("plant", "c1.speed").find("ssc:Real", NS).get("unit") == "m/s"  # from the plant's port table
    assert connector("plant", "c1.load_force").find("ssc:Real", NS).get("unit") == "N"
    assert connector("plant", "pe_c1.blocked").find("ssc:Boolean", NS) is not None
    units = {u.get("name"): u.find("ssc:BaseUnit", NS).attrib for u in ssd.iterfind("ssd:Units/ssc:Unit", NS)}
    assert units["m/s"] == {"m": "1", "s": "-1"} and units["N"] == {"kg": "1", "m": "1", "s": "-2"}
    links = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
             for c in ssd.iterfind("ssd:System/ssd:Connections/ssd:Connection", NS)]
    assert len(links) == 20
    assert ("drive_c3", "belt_speed", "plant", "c3.speed") in links
    assert ("plant", "pe_c4.blocked", "controller", "pe_4") in links
    assert ssd.find("ssd:DefaultExperiment", NS).get("stopTime") == "16.0"
    values = {p.get("name"): p[0].get("value") for p in _xml(paper_ssp, "resources/controller.ssv").iterfind(
        "ssv:Parameters/ssv:Parameter", NS)}
    assert values["speed_4"] == "1.25" and values["n_belts"] == "4" and values["jam_stop"] == "false"
    plant = {p.get("name"): p[0].get("value") for p in _xml(paper_ssp, "resources/plant.ssv").iterfind(
        "ssv:Parameters/ssv:Parameter", NS)}
    assert plant == {"seed": "1", "fish_count": "4"}


@pytest.fixture(scope="module")
def gain_ssp(tmp_path_factory) -> Path:
    """The paper's test with controller.setpoint_2 -> drive_c2.speed_setpoint through gain 0.9 and offset 0.01."""
    tmp_path = tmp_path_factory.mktemp("gain")
    text = PAPER.read_text().replace('"controller.setpoint_2 -> drive_c2.speed_setpoint",\n', "")
    text += ('\n[[wiring.connection]]\nfrom = "controller.setpoint_2"\nto = "drive_c2.speed_setpoint"\n'
             'gain = 0.9\noffset = 0.01\n')
    scenario = tmp_path / "gain.toml"
    scenario.write_text(text)
    out = tmp_path / "gain.ssp"
    assert export(scenario, out, "fish.count=2").returncode == 0
    return out


def test_a_gain_and_offset_are_written_as_the_standards_linear_transformation(gain_ssp):
    out = gain_ssp
    ssd = _xml(out, "SystemStructure.ssd")
    c = ssd.find("ssd:System/ssd:Connections/ssd:Connection[@endElement='drive_c2'][@endConnector='speed_setpoint']",
                 NS)
    assert c.find("ssc:LinearTransformation", NS).attrib == {"factor": "0.9", "offset": "0.01"}
    back = load_scenario(out)  # fishfmu's import takes it as the gain and offset it was
    table = [t for t in back.wiring.connection if t.to == "drive_c2.speed_setpoint"]
    assert [(t.gain, t.offset) for t in table] == [(0.9, 0.01)]
    pytest.importorskip("libcosimpy")  # and libcosim applies it: 0.9 x 0.5 m/s + 0.01 m/s once c2 runs
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver
    ex = CosimExecution.from_ssp_file(str(out))
    idx = {i.name.decode(): i.index for i in ex.slave_infos()}
    ref = {n: {v.name.decode(): v.reference for v in ex.slave_variables(i)} for n, i in idx.items()}
    observer = CosimObserver.create_last_value()
    ex.add_observer(observer)
    for _ in range(500):
        assert ex.step()
    ex.stop()
    source = observer.last_real_values(idx["controller"], [ref["controller"]["setpoint_2"]])[0]
    target = observer.last_real_values(idx["drive_c2"], [ref["drive_c2"]["speed_setpoint"]])[0]
    assert source == 0.5 and target == pytest.approx(0.46, abs=1e-12)


def test_fmpys_ssp_reader_parses_it(paper_ssp):
    from fmpy.ssp.ssd import read_ssd
    ssd = read_ssd(str(paper_ssp))
    comps = {c.name: c for c in ssd.system.elements}
    assert set(comps) == {"controller", "drive_c1", "drive_c2", "drive_c3", "drive_c4", "plant"}
    assert comps["plant"].source == "resources/fishfmu_plant.fmu"
    assert {c.name for c in comps["plant"].connectors} >= {"c1.speed", "pe_c4.blocked", "seed", "fish_count"}
    assert len(ssd.system.connections) == 20
    assert ssd.system.connections[0].startElement == "controller"
    bound = {p.name: (p.type, p.value) for p in comps["controller"].parameterBindings[0].parameterValues[0].parameters}
    assert bound["speed_4"] == ("Real", "1.25") and bound["n_belts"] == ("Integer", "4")  # the SSV, read through fmpy


def _same_runs(a, b) -> None:
    ka, kb = dict(a.kpis), dict(b.kpis)
    ka.pop("expect", None), kb.pop("expect", None)  # [expect] is what SSP cannot carry: listed, not in the archive
    assert ka == kb
    assert list(a.signals.columns) == list(b.signals.columns)
    assert np.array_equal(a.signals.to_numpy(dtype=float), b.signals.to_numpy(dtype=float), equal_nan=True)


def test_fishfmu_reads_the_paper_test_back_to_the_same_kpis_bit_for_bit(paper_ssp):
    back = load_scenario(paper_ssp)
    assert [f.name for f in back.fmu] == ["controller", "drive_c1", "drive_c2", "drive_c3", "drive_c4"]
    assert (back.run.seed, back.fish.count, back.run.duration_s) == (1, 4, 16.0)
    original, again = run_scenario(load_scenario(PAPER, SHORT)), run_scenario(back)
    assert original.kpis["arrival_t_s"]["pe_c2"]["f01"] is not None  # fish went through two belts
    _same_runs(original, again)


def test_user_fmu_is_carried_as_given_and_read_back_to_the_same_kpis(tmp_path, user_drive):
    sets = {**SHORT, "fmu[1].path": str(user_drive)}
    out = tmp_path / "user.ssp"
    cli = export(USER_FMU, out, *(f"{k}={v}" for k, v in sets.items()))
    assert cli.returncode == 0, cli.stderr
    ssd = _xml(out, "SystemStructure.ssd")
    source = {c.get("name"): c.get("source") for c in ssd.iterfind("ssd:System/ssd:Elements/ssd:Component", NS)}
    assert source["drive_c2"] == source["drive_c3"] != source["drive_c1"]  # two files named conveyor_drive.fmu
    with zipfile.ZipFile(out) as zf:  # the user's file byte for byte, beside the built-in drive of the same name
        assert zf.read(source["drive_c1"]) == user_drive.read_bytes()
        assert zf.read(source["drive_c2"]) == builtin_fmu("conveyor_drive").read_bytes() != user_drive.read_bytes()
    values = {p.get("name"): p[0].get("value") for p in _xml(out, "resources/drive_c1.ssv").iterfind(
        "ssv:Parameters/ssv:Parameter", NS)}
    assert values == {"running_resistance_coulomb": "30.0"}
    _same_runs(run_scenario(load_scenario(USER_FMU, sets)), run_scenario(load_scenario(out)))


@pytest.mark.slow
@pytest.mark.parametrize("scenario", [PAPER, USER_FMU], ids=["paper_test", "user_fmu"])
def test_full_length_read_back_gives_the_same_kpis(tmp_path, scenario, user_drive):
    sets = {"fmu[1].path": str(user_drive)} if scenario == USER_FMU else {}
    out = tmp_path / "line.ssp"
    assert export(scenario, out, *(f"{k}={v}" for k, v in sets.items())).returncode == 0
    original = run_scenario(load_scenario(scenario, sets))
    assert original.kpis["throughput_time_s"] is not None  # the whole batch went through
    _same_runs(original, run_scenario(load_scenario(out)))


def test_libcosim_loads_and_runs_it_as_fishfmus_jacobi_run(paper_ssp):
    pytest.importorskip("libcosimpy")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    n = 1600  # the archive's 16 s: fish reach the second beam at 13 s
    log_output_level(CosimLogLevel.ERROR)
    ex = CosimExecution.from_ssp_file(str(paper_ssp))  # the step from the archive's OSP annotation
    idx = {info.name.decode(): info.index for info in ex.slave_infos()}
    assert set(idx) == {"controller", "drive_c1", "drive_c2", "drive_c3", "drive_c4", "plant"}
    var = {name: {v.name.decode(): v.reference for v in ex.slave_variables(i)} for name, i in idx.items()}
    observer = CosimObserver.create_last_value()
    ex.add_observer(observer)
    rows = []
    for _ in range(n):
        assert ex.step()
        eyes = observer.last_boolean_values(idx["plant"], [var["plant"][f"pe_c{i}.blocked"] for i in range(1, 5)])
        sp = observer.last_real_values(idx["controller"], [var["controller"][f"setpoint_{i}"] for i in range(1, 5)])
        rows.append([*eyes, *sp])
    ex.stop()
    theirs = np.array(rows, dtype=float)
    # libcosim's fixed-step master is Jacobi: every component sees the others' values of the step before
    sc = load_scenario(paper_ssp, {"run.coupling": "jacobi", "run.stop_when_clear": False,
                                   "run.duration_s": n * 0.01})
    s = run_scenario(sc).signals
    eyes = s[[f"plant.pe_c{i}.blocked" for i in range(1, 5)]].to_numpy(dtype=float)
    setpoints = s[[f"controller.setpoint_{i}" for i in range(1, 5)]].to_numpy(dtype=float)
    assert eyes[:, 1].sum() > 0  # fish reached the second beam
    # the SSV values reached the FMUs: the controller's setpoint for c4 is its speed_4 = 1.25 once started
    assert theirs[-1, 7] == 1.25
    assert np.array_equal(theirs[:, :4], eyes)  # every beam, every step: the plant with the same fish and speeds
    assert theirs[:, 4:] == pytest.approx(setpoints, abs=1e-9)


def test_what_ssp_cannot_say_is_printed_and_in_the_archive(tmp_path):
    text = PAPER.read_text() + ('\n[[event]]\nt_s = 5.0\ntarget = "drive_c2.speed_setpoint"\naction = "override"\n'
                                'value = 0.0\n\n[record]\nvariables = ["drive_c1.motor_speed"]\n')
    scenario = tmp_path / "events.toml"
    scenario.write_text(text.replace('name = "drive_c3"\nbuiltin = "conveyor_drive"',
                                     'name = "drive_c3"\nbuiltin = "conveyor_drive"\nstep_multiple = 2'))
    out = tmp_path / "events.ssp"
    cli = export(scenario, out)
    assert cli.returncode == 0, cli.stderr
    with zipfile.ZipFile(out) as zf:
        notes = zf.read("resources/fishfmu-not-in-ssp.txt").decode()
    for said in ("[[event]] at 5.0 s: override drive_c2.speed_setpoint 0.0", "[expect] lost: max = 0.0",
                 "[record] variables = ['drive_c1.motor_speed']", "fmu 'drive_c3': step_multiple = 2",
                 "run.seed = 1 and fish.count = 18"):
        assert said in notes and said in " ".join(cli.stdout.split()), said


def test_export_never_writes_over_a_users_file_and_refuses_another_suffix(tmp_path):
    mine = tmp_path / "line.ssp"
    mine.write_bytes(b"the user's own file")
    cli = export(PAPER, mine)
    assert cli.returncode == 2 and "line.ssp" in cli.stderr and len(cli.stderr.strip().splitlines()) == 1
    assert mine.read_bytes() == b"the user's own file"
    cli = export(PAPER, tmp_path / "line.zip")
    assert cli.returncode == 2 and "--out" in cli.stderr and not (tmp_path / "line.zip").exists()


def test_an_ssp_without_the_plant_is_not_a_scenario_of_its_own(tmp_path, paper_ssp):
    ssd = (tmp_path / "SystemStructure.ssd")
    with zipfile.ZipFile(paper_ssp) as zf:
        zf.extractall(tmp_path)
    root = etree.parse(str(ssd)).getroot()
    plant = root.find("ssd:System/ssd:Elements/ssd:Component[@name='plant']", NS)
    plant.getparent().remove(plant)
    for c in root.findall("ssd:System/ssd:Connections/ssd:Connection", NS):
        if "plant" in (c.get("startElement"), c.get("endElement")):
            c.getparent().remove(c)
    ssd.write_bytes(etree.tostring(root))
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "check", str(ssd)], capture_output=True, text=True)
    assert cli.returncode == 2 and "no fishfmu plant component" in cli.stderr


def test_as_system_ssp_of_a_scenario_file_the_plant_component_is_the_files_plant(tmp_path, paper_ssp):
    from fishfmu.scenario.schema import resolved_toml
    scenario = tmp_path / "resolved.toml"  # what a run of the archive writes as scenario.resolved.toml
    scenario.write_text(resolved_toml(load_scenario(paper_ssp)))
    again = load_scenario(scenario)
    assert [f.name for f in again.fmu] == ["controller", "drive_c1", "drive_c2", "drive_c3", "drive_c4"]
    assert ("drive_c1.belt_speed", "plant.c1.speed") in [(t.from_, t.to) for t in again.wiring.connection]
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "check", str(scenario), "--set", "run.seed=2"],
                         capture_output=True, text=True)
    assert cli.returncode == 2 and "seed = 1" in cli.stderr and "run.seed = 2" in cli.stderr


def test_fmpys_simulate_ssp_runs_it_without_its_bindings_or_transformations(gain_ssp):
    """What fmpy 0.3.32's SSP simulation does not take from a conforming file (said in docs/scenarios.md)."""
    from fmpy.ssp.simulation import simulate_ssp
    r = simulate_ssp(str(gain_ssp), stop_time=5.0, step_size=0.01)
    # the controller at its built-in default speed_4 = 1.3 m/s, not the 1.25 of its SSV
    assert r["controller.setpoint_4"][-1] == 1.3
    # speed_2 at its default 0.55 m/s (the SSV's is 0.5), copied as it is: no factor 0.9, no offset 0.01 (0.505)
    assert r["drive_c2.speed_setpoint"][-1] == r["controller.setpoint_2"][-1] == 0.55
