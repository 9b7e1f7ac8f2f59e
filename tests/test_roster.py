"""The fish roster's answers follow every fish that comes and goes: which are due (none before the first drop, the
next after a release), which slots are on the line (per slot, per body, per joint), after each release, retirement
and rebuild."""

from __future__ import annotations

import numpy as np

from plant.sim.roster import ADMIT_AHEAD_S, FishRoster
from plant.sim.state import FishStatus
from tests.plant_helpers import fish


def three_fish() -> FishRoster:
    return FishRoster.of([fish("a", t_s=0.5), fish("b", t_s=2.0), fish("c", t_s=2.0)])


def test_fish_are_due_from_their_drop_time_and_no_longer_once_released():
    roster = three_fish()
    assert roster.due(0.49) == [] and roster.due(0.5) == [0]
    assert roster.due(1.0 - 1e-9, ADMIT_AHEAD_S) == [0] and roster.due(1.0, ADMIT_AHEAD_S) == [0, 1, 2]
    roster.seated(np.array([0, 1, 2]))
    roster.released(0, 0.0)
    assert roster.due(1.9) == [] and roster.due(2.0) == [1, 2]  # the next drop, not the one released
    roster.released(1, 0.0)
    roster.released(2, 0.01)
    assert roster.due(100.0) == []
    assert [d.fish_id for d in roster.drop_adjustments] == ["c"]


def test_the_on_line_masks_follow_releases_retirements_and_rebuilds():
    roster = three_fish()
    roster.seated(np.array([0, 1]))
    assert roster.on_line_slots().tolist() == [False, False]
    roster.released(1, 0.0)
    assert roster.on_line_slots().tolist() == [False, True]
    assert roster.on_line_slots(4).tolist() == [False] * 4 + [True] * 4  # per body of a four-body fish
    assert roster.on_line_slots(3).tolist() == [False] * 3 + [True] * 3  # per joint
    roster.released(0, 0.0)
    assert roster.on_line_slots().tolist() == [True, True] and roster.on_line_slots(4).tolist() == [True] * 8
    roster.retired(1, 0)  # taken off by device 0
    assert roster.on_line_slots().tolist() == [True, False] and roster.status[1] == FishStatus.REJECTED
    assert roster.on_line_slots(4).tolist() == [True] * 4 + [False] * 4
    roster.seated(np.array([2, 0]))  # rebuilt without the fish gone, the next one parked in the first slot
    assert roster.on_line_slots().tolist() == [False, True]
    assert roster.on_line_slots(4).tolist() == [False] * 4 + [True] * 4
    roster.released(2, 0.0)
    assert roster.on_line_slots(2).tolist() == [True, True, True, True]
    mask = roster.on_line_slots()
    assert not mask.flags.writeable  # shared between the step's readers: none may change it
