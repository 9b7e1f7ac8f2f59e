"""No fish pushed through a belt: the dumped paper test (18 fish within a few seconds onto the infeed, a pile
several fish deep) over 50 seeds.  A belt is a one-sided surface in the contact model; under a pile a light
body (the tail fin) can be pushed past it, and what keeps it above is the contact stiffness against the step
(``plant.sim.params.NumericsParams``).  Any change to those numbers (or to the contact geometry) is judged here.

Both fish models are judged, each at its own step and sphere spacing (``plant.sim.params.FISH_NUMERICS``): the
paper's five bodies at 1.25 ms, and the joined fish (the default: the tail fin part of the tail) at 2 ms with spheres
three radii apart (at 2.5 ms seed 13 put a body centre 0.9 mm below the infeed).

Marked slow: 50 runs of about 9 CPU seconds each per model (``pytest -m slow tests/test_dumps.py``, 4-5 min on two
cores for the paper's fish; the joined fish's 7.7 min with -n 0 on the shared 2-core machine, 2026-11-28).
The check is stricter than the run's own health check (a body 8 cm below a belt): every body's centre, sampled at
25 Hz while its fish is on the line, stays above the belt's surface wherever there is a belt under it (a body lying
on a belt has its centre half the fish's thickness above it, 2-4 cm).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from plant.sim.state import FishStatus

from fishfmu.cosim.runner import run_scenario
from fishfmu.scenario.schema import load_scenario

PAPER_DUMP = Path(__file__).parents[1] / "scenarios" / "paper_dump.toml"
MODELS = {"paper5": {"plant.fish_model": "paper5"}, "joined4": {"plant.fish_model": "joined4"}}
"""Each fish model, with the step and spacing it brings."""
DRUM_CLEARANCE_M = 0.1
"""Within this distance of a belt's end a body may hang over the drum or sag into the transfer gap."""


def lowest_body_over_a_belt(poses: dict[str, np.ndarray], line) -> tuple[float, float, float]:
    """(height of the lowest body centre above the belt under it [m], its time [s], its x [m]) over the run,
    counting only bodies of fish on the line that are over a belt, clear of its ends."""
    bodies_per_fish = poses["pos"].shape[1] // poses["status"].shape[1]
    on = np.repeat(poses["status"] == FishStatus.ON_LINE, bodies_per_fish, axis=1)
    x, z = poses["pos"][:, :, 0], poses["pos"][:, :, 2]
    height = np.full(x.shape, np.inf)
    for c in line.conveyors:
        over = on & (x > c.x_start_m + DRUM_CLEARANCE_M) & (x < c.x_end_m - DRUM_CLEARANCE_M)
        height = np.where(over, np.minimum(height, z - c.z_top_m), height)
    f, b = np.unravel_index(int(np.argmin(height)), height.shape)
    return float(height[f, b]), float(poses["t_s"][f]), float(x[f, b])


@pytest.mark.slow
@pytest.mark.parametrize("model", list(MODELS))
@pytest.mark.parametrize("seed", range(1, 51))
def test_no_fish_is_pushed_through_a_belt_in_a_dumped_batch(seed: int, model: str) -> None:
    scenario = load_scenario(PAPER_DUMP, {"run.seed": seed, **MODELS[model]})
    result = run_scenario(scenario, record_poses=True)
    assert result.status == "ok", result.error
    height_m, t_s, x_m = lowest_body_over_a_belt(result.poses, scenario.line)
    print(f"{model} seed {seed}: closest body centre {height_m * 1e3:.1f} mm above the belt at t = {t_s:.2f} s, "
          f"x = {x_m:.2f} m")  # the closest approach, shown with pytest -s or -rA
    assert height_m > 0.0, f"seed {seed}: a body centre {-height_m * 1e3:.1f} mm below the belt at t = {t_s:.2f} s, x = {x_m:.2f} m"
