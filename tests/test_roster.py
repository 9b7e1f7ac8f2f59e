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


def test_the_next_rebuild_is_foreseen_as_the_plant_will_make_it():
    """Steps of 0.1 s.  Fish b (2.0 s) and a (0.5 s) are in the system's slots 0 and 1, a on the line; c (2.0 s),
    d (2.05 s) and e (3.5 s) wait outside it.  The admission comes at the first step whose start reaches c's drop,
    step 20 (t = 2.0); b, seated, is released at that same step, after the rebuild: so it is parked again, after a
    (on the line), with c and d (due within the second) in drop order; e (3.5 s) is beyond the second."""
    roster = FishRoster.of([fish("a", t_s=0.5), fish("b", t_s=2.0), fish("c", t_s=2.0), fish("d", t_s=2.05),
                            fish("e", t_s=3.5)])
    roster.seated(np.array([1, 0]))
    roster.released(0, 0.0)
    no_x = np.zeros(2)
    assert roster.next_rebuilds(17, 0.1, no_x) == [[0, 1, 2, 3]]  # from step 17 (0.3 s ahead); no retirement
    # b seated with an earlier drop (1.85 s): released at step 19, on the line (in its slot, 0) at the admission
    early = FishRoster.of([fish("a", t_s=0.5), fish("b", t_s=1.85), fish("c", t_s=2.0), fish("d", t_s=2.05)])
    early.seated(np.array([1, 0]))
    early.released(0, 0.0)
    assert early.next_rebuilds(17, 0.1, no_x) == [[1, 0, 2, 3]]
    early.released(1, 0.0)  # the plant releases b at step 19; the foresight from step 19 on says the same
    assert early.next_rebuilds(19, 0.1, no_x) == [[1, 0, 2, 3]]


def test_the_next_retirement_keeps_all_but_the_fish_furthest_downstream():
    """Eight fish on the line, a ninth waiting outside the system (due at 5 s): a rebuild is due once two have gone
    (a quarter, two at least).  Foreseen: the admission (all eight, then the ninth) and the retirement; none gone:
    the two furthest downstream are taken as leaving; one gone (parked, still in its slot): the one furthest
    downstream of those left."""
    roster = FishRoster.of([fish(f"f{i}", t_s=0.1 * i) for i in range(8)] + [fish("late", t_s=5.0)])
    roster.seated(np.arange(8))
    for k in range(8):
        roster.released(k, 0.0)
    rear_x = np.array([5.0, 4.0, 7.0, 1.0, 6.9, 2.0, 3.0, 0.5])
    admission = list(range(9))
    assert roster.next_rebuilds(100, 0.01, rear_x) == [admission, [0, 1, 3, 5, 6, 7]]  # 2 (7.0 m), 4 (6.9 m) leave
    roster.retired(2, -1)
    admission.remove(2)
    assert roster.next_rebuilds(100, 0.01, rear_x) == [admission, [0, 1, 3, 5, 6, 7]]  # then 4, furthest of the rest
    roster.retired(4, -1)  # two gone: the plant rebuilds now; in this system only the admission is left to foresee
    admission.remove(4)
    assert roster.next_rebuilds(100, 0.01, rear_x) == [admission]
