"""The one step loop's observers (plant.sim.observers): every way of stepping the plant (a run of the plant alone, a
co-simulation as `fishfmu run` and `fishfmu serve` step it, the plant as an FMU) attaches the same ones: the energy
watch, then the fish counts."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from plant.sim.health import EnergyWatch
from plant.sim.observers import FishCounts, plant_observers
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
