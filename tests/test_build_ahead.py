"""Laying out a rebuild's system ahead (what a run served in real time does with the wall time its steps leave
over) changes nothing the plant computes: the same run, stepped with and without it, is the same to the bit, and
the rebuilds it foresaw used the layout made ahead."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from plant.sim import plant as plant_module
from plant.sim.params import PlantParams
from plant.sim.plant import Plant
from plant.sim.state import FishStatus
from plant.sim.system import member_keys
from tests.plant_helpers import fish, straight_line


def run(ahead: bool, params: PlantParams | None = None) -> tuple[Plant, list[np.ndarray], list[str], list[str]]:
    """Eight fish dropped 0.7 s apart onto a 1.2 m belt at 0.8 m/s (admissions; fish leaving its end:
    retirements), 6.5 s; the state after every step; per rebuild, whether a layout made ahead for its fish was
    used ("used"), those made were for others ("other"), or there were none, and what asked for it (the plant's
    method)."""
    line = straight_line(("c1", 0.0, 1.2, 0.0), photoeyes=(("pe1", 1.0, 0.015),))
    plant = Plant(line, [fish(f"f{i}", x_m=0.35, t_s=0.05 + 0.7 * i) for i in range(8)], params)
    used: list[str] = []
    build = plant_module.build_model

    def watched(surfaces, members, params, gravity, line_, highest, laid=()):
        used.append("used" if any(a.planned == member_keys(members) for a in laid) else "other" if laid else "none")
        return build(surfaces, members, params, gravity, line_, highest, laid)

    plant_module.build_model = watched
    callers: list[str] = []
    rebuild = plant._rebuild

    def asked(t):  # the method that asked, and where the retirements' rebuild was made
        caller = sys._getframe(1)
        callers.append(caller.f_code.co_name if caller.f_code.co_name != "_rebuild_for_retired" else
                       "retired, in " + caller.f_back.f_code.co_name)
        rebuild(t)

    plant._rebuild = asked
    try:
        states = []
        for _ in range(650):
            out = plant.step({"c1": 0.8})
            if ahead:
                plant.build_ahead(1.0)  # all the time it takes: every foreseen layout complete
            s = plant.state
            states.append(np.concatenate([s.pos.ravel(), s.vel.ravel(), s.status.astype(float),
                                          [float(out.photoeyes["pe1"])]]))
    finally:
        plant_module.build_model = build
    return plant, states, used, callers


@pytest.mark.parametrize("extension", ["none", "direction_friction"])
def test_a_run_steps_the_same_to_the_bit_with_its_rebuilds_laid_out_ahead(extension):
    """With directional friction a fish's friction level, part of what a layout is made for, changes as it slips:
    a layout made for the levels of a moment before may not fit, and is then not used."""
    params = PlantParams.model_validate({"extensions": {"direction_friction": {"head": 0.7, "tail": 1.4}}}
                                        if extension == "direction_friction" else {})
    plain, plain_states, plain_used, plain_callers = run(False, params)
    ahead, ahead_states, ahead_used, ahead_callers = run(True, params)
    assert all(s == "none" for s in plain_used)
    assert len(plain_states) == len(ahead_states)
    for k, (a, b) in enumerate(zip(plain_states, ahead_states)):
        assert a.shape == b.shape and np.array_equal(a, b), f"step {k + 1} differs"
    # every fish came and went: admissions and retirements, laid out ahead where their fish were foreseen
    assert np.all(ahead.status == FishStatus.LEFT)
    assert len(ahead_used) >= 5 and all(u != "none" for u in ahead_used), ahead_used
    # the rebuilds of the admissions and of the retirements made in the time left over before the next step
    assert plain_callers.count("_admit_and_release") >= 2 and plain_callers.count("retired, in step") >= 2
    assert ahead_callers.count("build_ahead") == plain_callers.count("_admit_and_release"), ahead_callers
    assert ahead_callers.count("retired, in build_ahead") == plain_callers.count("retired, in step"), ahead_callers
    assert len(ahead_callers) == len(plain_callers)
    if extension == "none":  # the levels never change: most guesses right (one missed is built then)
        assert ahead_used.count("used") >= len(ahead_used) - 2, ahead_used
