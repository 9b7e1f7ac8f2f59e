"""The one step loop's observers (plant.sim.observers): every way of stepping the plant (a run of the plant alone, a
co-simulation as `fishfmu run` and `fishfmu serve` step it, the plant as an FMU) attaches the same ones: the energy
watch, the fish counts, the recording (not in the plant FMU); a script's own observer sees every step of each, and
fishfmu serve's publication is one too."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from plant.sim.health import EnergyWatch
from plant.sim.observers import FishCounts, Recording, plant_observers
from plant.sim.simulate import simulate_plant
from plant.sim.state import FishStatus
from tests.plant_helpers import fish, straight_line

from fishfmu.cosim.build import build, checked, scenario_fish
from fishfmu.scenario.schema import load_scenario

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
W, ON, LEFT, REJ = FishStatus.WAITING, FishStatus.ON_LINE, FishStatus.LEFT, FishStatus.REJECTED


def _step(status: list[int], outfeed_blocked: bool) -> tuple[SimpleNamespace, SimpleNamespace]:
    return (SimpleNamespace(status=np.array(status, dtype=np.int8)),
            SimpleNamespace(photoeyes={"pe_out": outfeed_blocked, "pe_in": True}))


def test_fish_counts_count_each_status_and_each_head_at_the_outfeed_once() -> None:
    counts = FishCounts("pe_out")
    # five steps, hand-made: the outfeed beam blocked over steps 2-3 and again at 5 (two heads); pe_in ignored
    steps = [([W, W, W, W, W], False), ([ON, W, W, W, W], False), ([ON, ON, W, W, W], True),
             ([LEFT, ON, ON, W, W], True), ([LEFT, REJ, ON, ON, W], False), ([LEFT, REJ, LEFT, ON, ON], True)]
    for status, blocked in steps:
        counts.after_step(*_step(status, blocked), None, 0.01)
    assert counts.values == {"fish_waiting": 0, "fish_dropped": 5, "fish_on_line": 2, "fish_left": 2,
                             "fish_rejected": 1, "outfeed_count": 2}


def test_every_way_of_stepping_the_plant_attaches_the_energy_watch_then_the_fish_counts() -> None:
    kinds = [type(o) for o in plant_observers()]
    assert kinds == [EnergyWatch, FishCounts]
    sc = load_scenario(PAPER, {"fish.count": 2, "expect": {}})
    with checked(sc) as c, build(c, scenario_fish(sc)) as sim:
        assert [type(sim.energy_watch), type(sim.fish_counts)] == kinds
        assert sim.fish_counts.outfeed == "pe_c4"
    from fishfmu.cosim.plant_fmu import PlantInFmu
    pim = PlantInFmu(PAPER, report=lambda m: None)
    pim.start()
    assert [type(o) for o in pim.watches] == kinds and pim.watches[1].outfeed == "pe_c4"


def test_an_observer_attached_to_the_plant_alone_sees_every_step_after_the_watches() -> None:
    line = straight_line(("c1", 0.0, 2.0, 0.0))
    seen: list[tuple[float, int]] = []

    class Seen:
        def after_step(self, state, outputs, inputs, dt_s):  # noqa: ANN001, ANN202
            seen.append((round(state.t_s, 9), int(np.count_nonzero(state.status == ON))))

    run = simulate_plant(line, [fish("f01", t_s=0.0)], {"c1": 0.3}, 0.1, stop_when_clear=False,
                         observers=[Seen()])
    assert [t for t, _ in seen] == [round(0.01 * k, 9) for k in range(1, 11)]
    assert run.t_end_s == pytest.approx(0.1) and seen[-1][1] == 1


def test_the_co_simulation_counts_the_fish_and_the_outfeed_heads_its_run_recorded() -> None:
    sc = load_scenario(PAPER, {"fish.count": 3, "run.duration_s": 40.0, "expect": {}})
    with checked(sc) as c, build(c, scenario_fish(sc)) as sim:
        while sim.t_s < sc.run.duration_s - 1e-9:
            sim.step()
        status = sim.plant.state.status
        heads = sim.recorder.tables()["photoeyes"].query("sensor_id == 'pe_c4'")
        still_blocked = bool(sim.values["plant.pe_c4.blocked"])
        counted = sim.fish_counts.values
    assert counted["fish_left"] == int(np.count_nonzero(status == LEFT)) >= 1  # some fish got through
    assert counted["fish_waiting"] == int(np.count_nonzero(status == W)) and counted["fish_dropped"] == 3
    assert counted["outfeed_count"] == len(heads) + still_blocked >= 1


def test_the_plant_fmu_stops_on_energy_from_nowhere_as_a_run_does() -> None:
    # a hand-made blow-up: a fish on the line thrown upwards at 5 m/s (well below the 25 m/s speed limit, so
    # only the energy watch can catch it); the FMU refuses that doStep (fmi2Discard) naming the fish
    from fishfmu.cosim.plant_fmu import PlantInFmu
    logged: list[str] = []
    pim = PlantInFmu(PAPER, report=logged.append)
    pim.parameter_setter("fish_count")(2)
    for c in pim.conveyor_ids:
        pim.speed_setter(f"{c}.speed")(0.3)
    pim.start()
    for _ in range(100):  # until a fish has landed and rides a belt (the first drop is at 4 s)
        assert pim.do_step(0.1), logged
        if pim.values["fish_on_line"] and pim.plant.state.t_s > 5.0:
            break
    k = int(np.flatnonzero(pim.plant.state.status == ON)[0])
    assert logged == []
    sd = pim.plant.model.mbs.systemData
    v = sd.GetODE2Coordinates_t()
    bodies = np.flatnonzero(pim.plant.state.fish_of_body == k)  # fish k's bodies in the Exudyn system
    v[pim.plant.model.body_ltg[bodies, 2]] = 5.0
    sd.SetODE2Coordinates_t(v)
    assert not pim.do_step(0.01)
    assert len(logged) == 1 and "the plant stopped" in logged[0] and "more energy than the belts supplied" in logged[0]
    assert f"fish '{pim.plant.state.fish_ids[k]}'" in logged[0]
    assert not pim.do_step(0.01)  # the steps after it are refused, as after any stop


# ---- the one loop's observers in every way of stepping (issue 42) ----------------------------------------------
SERVED = ROOT / "scenarios" / "paper_opcua.toml"


class Seen:
    """A script's own observer: the end time of every step it saw, and the step's length."""

    def __init__(self) -> None:
        self.t_s: list[float] = []

    def after_step(self, state, outputs, inputs, dt_s):  # noqa: ANN001, ANN202
        assert set(inputs.belt_speed_mps) == set(outputs.belt_speed_mps)  # what the step was given, by belt
        self.t_s.append(round(state.t_s, 9))
        assert dt_s == pytest.approx(0.01)


def _every_step(n: int) -> list[float]:
    return [round(0.01 * k, 9) for k in range(1, n + 1)]


def test_a_scripts_observer_sees_every_step_of_a_run_attached_once_after_the_watches_and_the_recording() -> None:
    from fishfmu.cosim.runner import run_scenario
    sc = load_scenario(PAPER, {"fish.count": 1, "run.duration_s": 0.3, "expect": {}})
    seen = Seen()
    res = run_scenario(sc, observers=[seen])
    assert seen.t_s == _every_step(30) and res.status == "ok"
    with checked(sc) as c, build(c, scenario_fish(sc), observers=[seen]) as sim:
        attached = [sim.energy_watch, sim.fish_counts, *sim.recording, *sim.observers]
    assert [type(o) for o in attached] == [EnergyWatch, FishCounts, Recording, Seen]
    assert attached[2].recorder is sim.recorder


def test_a_scripts_observer_sees_every_step_of_the_plant_fmu_and_it_records_nothing() -> None:
    from fishfmu.cosim.plant_fmu import PlantInFmu
    seen = Seen()
    pim = PlantInFmu(PAPER, report=lambda m: None, observers=[seen])
    pim.start()
    assert pim.do_step(0.05) and pim.do_step(0.02)
    assert seen.t_s == _every_step(7)
    assert [type(o) for o in pim.watches] == [EnergyWatch, FishCounts, Seen]  # no recording: the host records


def _free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_scripts_observer_sees_every_step_served_in_lockstep_and_again_after_a_reset() -> None:
    """The served line, in-process, stepped as a client's step(n) steps it (no client needed): the observers are
    attached to each run the line builds, once; the publication's belt travel is the sum of the steps' speeds."""
    pytest.importorskip("asyncua")
    import asyncio
    from fishfmu.serve.line import LineServer
    from fishfmu.serve.publication import Publication
    sc = load_scenario(SERVED, {"fish.count": 1, "run.duration_s": 1.0, "expect": {}})
    seen, travelled = Seen(), {}

    def on_ready(line: LineServer) -> None:
        async def client() -> None:
            assert await line.space.write_input("drive_c4.speed_setpoint", 1.0)  # as a PLC's (or Modbus's) write
            await line.step(7)
            await line.step(5)
            travelled["before"] = line.publication.travel_m.copy()
            await line.reset()  # forgets the write
            assert await line.space.write_input("drive_c3.speed_setpoint", 0.5)
            await line.step(3)
            await line.stop()
        tasks.append(asyncio.get_running_loop().create_task(client()))

    tasks: list = []
    with checked(sc, SERVED) as c:
        line = LineServer(c, endpoint=f"opc.tcp://127.0.0.1:{_free_port()}", observers=[seen])
        try:
            res = line.run(on_ready=on_ready)
        finally:
            line.close()
    assert tasks[0].done() and tasks[0].exception() is None
    assert seen.t_s == _every_step(12) + _every_step(3)
    attached = line.cosim.observers
    assert [type(o) for o in attached] == [Publication, Seen] and attached[0] is line.publication
    belts = res.run.belts  # the run after the reset, as recorded by its Recording observer
    assert sorted(belts.t_s.unique()) == pytest.approx([0.01, 0.02, 0.03])
    by_belt = belts.groupby("conveyor_id").speed_mps.sum() * 0.01
    ids = [cv.id for cv in sc.line.conveyors]
    assert line.publication.travel_m == pytest.approx(by_belt[ids].to_numpy(), abs=1e-12)
    assert travelled["before"][ids.index("c4")] > 0 and line.publication.travel_m[ids.index("c4")] == 0.0
    assert line.publication.travel_m[ids.index("c3")] > 0  # the run after the reset: its own travel, from rest


def test_the_recording_observer_logs_the_belts_as_the_master_sent_them_step_by_step() -> None:
    """belts.csv (the Recording observer, from the step's inputs) against signals.csv (the master's own row of what
    it sent): each belt's setpoint is its drive's setpoint signal as sent in that step, its speed the plant's input."""
    from fishfmu.cosim.runner import run_scenario
    sc = load_scenario(PAPER, {"fish.count": 1, "run.duration_s": 1.2, "expect": {}})
    res = run_scenario(sc)
    sources = res.wiring["setpoints"]
    signals = res.signals.set_index(res.signals.t_s.round(9))
    assert len(signals) == 120
    for c in [cv.id for cv in sc.line.conveyors]:
        belt = res.run.belts.query("conveyor_id == @c").set_index("t_s")
        assert sources[c] == f"drive_{c}.speed_setpoint" and belt.index.round(9).tolist() == signals.index.tolist()
        assert belt.setpoint_mps.tolist() == signals[sources[c]].astype(float).tolist()
        assert belt.speed_mps.tolist() == signals[f"plant.{c}.speed"].astype(float).tolist()
    assert res.run.belts.setpoint_mps.max() > 0 and res.run.belts.speed_mps.max() > 0  # a belt started


def test_the_recording_observer_logs_what_the_plant_alone_was_given() -> None:
    # hand-made inputs: c1 at 0.3 m/s for the steps starting before 0.05 s, then 0.6 m/s; the setpoint is the speed
    line = straight_line(("c1", 0.0, 2.0, 0.0))
    run = simulate_plant(line, [fish("f01", t_s=0.0)], lambda t: {"c1": 0.3 if t < 0.05 - 1e-9 else 0.6}, 0.1,
                         stop_when_clear=False)
    assert run.belts.t_s.round(9).tolist() == _every_step(10)
    assert run.belts.setpoint_mps.tolist() == run.belts.speed_mps.tolist() == [0.3] * 5 + [0.6] * 5
