"""Running the plant alone with prescribed belt speeds (no drives, no controller).

Used to test the physics, to re-simulate measured runs with their logged belt speeds, and as
the inner loop of the co-simulation's plant.  The co-simulation master has its own loop
(fishfmu.cosim.master) but records through the same :class:`plant.sim.recorder.RunRecorder` and attaches the
same step observers (:mod:`plant.sim.observers`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.contract.line import Line
from plant.sim.params import PlantParams
from plant.sim.plant import Plant
from plant.contract.measured import fish_to_frame
from plant.fish.population import FishSpec
from plant.sim.observers import StepInputs, StepObserver, notify, plant_observers
from plant.sim.recorder import RunRecorder, pose_record
from plant.sim.ports import PlantPorts
from plant.sim.state import DropAdjustment, FishStatus

BeltSpeeds = dict[str, float] | Callable[[float], dict[str, float]]
DeviceCommands = Callable[[float], dict[str, bool]]
"""Each device's command (by id) for the step starting at t (e.g. :func:`plant.contract.device_commands.command_schedule`)."""


@dataclass
class SimulatedRun:
    """A run as the measured-data format has it, plus what the simulation knows beyond that."""

    fish: pd.DataFrame
    tracks: pd.DataFrame
    photoeyes: pd.DataFrame
    belts: pd.DataFrame
    t_end_s: float
    wall_s: float
    drop_adjustments: list[DropAdjustment] = field(default_factory=list)
    fish_status: np.ndarray | None = None
    rejections: pd.DataFrame | None = None
    """The devices' rejections (rejections.csv); None from code that did not record them."""
    device_commands: pd.DataFrame | None = None
    """The devices' commands as the plant took them (device_commands.csv); None on a line without devices."""
    poses: dict[str, np.ndarray] | None = None
    """Every body's pose at 25 Hz and the bodies' outlines (:func:`plant.sim.recorder.pose_record`, the
    arrays of a run's poses.npz), when asked for with ``record_poses``."""

    @property
    def real_time_factor(self) -> float:
        return self.t_end_s / self.wall_s if self.wall_s > 0 else float("inf")


class ClearWatch:
    """When a run with ``stop_when_clear`` ends: ``clear_margin_s`` after every fish has left the line (the wait
    starts over while a fish is still WAITING to be dropped); no fish, no end."""

    def __init__(self, clear_margin_s: float) -> None:
        self.margin_s = clear_margin_s
        self.clear_since: float | None = None

    def done(self, t: float, status: np.ndarray) -> bool:
        """After the step that ended at ``t``, with the fish's ``status``: is the run over?"""
        if not len(status):
            return False
        if np.all(status >= FishStatus.LEFT):  # left at the end or taken off by a device
            self.clear_since = t if self.clear_since is None else self.clear_since
            return t - self.clear_since >= self.margin_s - 1e-9
        if np.any(status == FishStatus.WAITING):
            self.clear_since = None
        return False


class RunEnd:
    """Where a run ends by itself: after ``round(duration_s / dt_s)`` steps, or with ``stop_when_clear`` (and any
    fish) ``clear_margin_s`` after every fish has left the line (:class:`ClearWatch`).  The one rule of every loop
    that steps a run: :func:`run_loop` (the plant alone, ``fishfmu run``) and ``fishfmu serve``, whose steps a client
    or the wall clock calls one by one."""

    def __init__(self, duration_s: float, dt_s: float, stop_when_clear: bool = True,
                 clear_margin_s: float = 1.0) -> None:
        self.duration_s = duration_s
        self.n_steps = int(round(duration_s / dt_s))
        self.stop_when_clear = stop_when_clear
        self.clear = ClearWatch(clear_margin_s)

    def reached(self, steps: int, t: float, status: Callable[[], np.ndarray]) -> bool:
        """After ``steps`` steps, the last one ending at ``t``: is the run over?  ``status()`` gives the fish's
        (asked only with ``stop_when_clear``)."""
        return (self.stop_when_clear and self.clear.done(t, status())) or steps >= self.n_steps


def run_loop(step: Callable[[], None], t_s: Callable[[], float], status: Callable[[], np.ndarray], end: RunEnd,
             before_step: Callable[[], None] | None = None,
             on_progress: Callable[[float, float], None] | None = None) -> int:
    """The run loop of both the plant alone (:func:`simulate_plant`) and the co-simulation
    (fishfmu.cosim.runner): ``step()`` until the run's ``end`` (:class:`RunEnd`; ``status()`` gives the fish's).
    ``t_s()`` is the time after the last step.  ``before_step()`` is called before each step and stops the run by
    raising (a stop request); ``on_progress(t, duration_s)`` after every 50th step from the first, and
    ``on_progress(t, t)`` at the end.  Returns the number of steps taken."""
    steps = 0
    for k in range(end.n_steps):
        if before_step is not None:
            before_step()
        step()
        steps += 1
        t = t_s()
        if on_progress is not None and k % 50 == 0:
            on_progress(t, end.duration_s)
        if end.reached(steps, t, status):
            break
    if on_progress is not None:
        on_progress(t_s(), t_s())
    return steps


def simulate_plant(line: Line, fish: list[FishSpec], belt_speeds: BeltSpeeds, duration_s: float,
                   params: PlantParams | None = None, comm_step_s: float = 0.01, stop_when_clear: bool = True,
                   clear_margin_s: float = 1.0, joint_factors: list[tuple[float, float]] | None = None,
                   on_step: Callable[[Plant], None] | None = None, record_poses: bool = False,
                   device_commands: DeviceCommands | None = None,
                   observers: list[StepObserver] | None = None) -> SimulatedRun:
    """Simulate up to ``duration_s``; with ``stop_when_clear`` stop ``clear_margin_s`` after every
    fish has been dropped and has left the line.  ``device_commands``: the devices' commands at each step's start
    (None: every device stays home).  ``record_poses``: also keep every body's pose at
    25 Hz (``SimulatedRun.poses``, for a 3D replay; about 2 MB per 18 fish and 30 s in memory).  ``observers``:
    attached after :func:`plant.sim.observers.plant_observers` (the energy watch, the fish counts, the recording),
    called after every step (:mod:`plant.sim.observers`)."""
    plant = Plant(line, fish, params, comm_step_s, joint_factors)
    ports = PlantPorts.of(line)
    rec = RunRecorder([f.fish_id for f in fish], list(ports.conveyor_ids), list(ports.photoeye_ids), comm_step_s,
                      ports.device_ids, record_poses=record_poses)
    watching = [*plant_observers(recorder=rec), *(observers or [])]
    speed_fn = belt_speeds if callable(belt_speeds) else (lambda t, s=dict(belt_speeds): s)

    def step() -> None:
        speeds = speed_fn(plant.state.t_s)
        commands = device_commands(plant.state.t_s) if device_commands is not None else dict.fromkeys(ports.device_ids,
                                                                                                       False)
        out = plant.step(speeds, commands)
        # the belts' setpoints are the speeds given; a blow-up stops the run here, as in a co-simulation
        notify(watching, plant.state, out, StepInputs(out.belt_speed_mps, commands, speeds), comm_step_s)
        if on_step is not None:
            on_step(plant)

    t0 = time.perf_counter()
    run_loop(step, lambda: plant.state.t_s, lambda: plant.state.status,
             RunEnd(duration_s, comm_step_s, stop_when_clear, clear_margin_s))
    wall = time.perf_counter() - t0
    tables = rec.tables()
    state = plant.state
    return SimulatedRun(fish_to_frame(fish), tables["tracks"], tables["photoeyes"], tables["belts"],
                        state.t_s, wall, list(state.drop_adjustments), state.status.copy(), tables["rejections"],
                        tables["device_commands"], pose_record(rec, state))
