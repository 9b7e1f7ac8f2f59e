"""What a run produced (:class:`RunResult`) and how it met its ``expect`` bounds (:class:`ExpectResult`).

Apart from :mod:`fishfmu.cosim.runner` (which makes them and re-exports them) so that what only reads a
result (the outputs, the report) does not import the runner and the FMU machinery behind it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from plant.contract.measured import Dataset, Run
from plant.fish.population import FishSpec

from fishfmu.scenario.schema import Scenario


@dataclass
class ExpectResult:
    kpi: str
    value: float | None
    min: float | None
    max: float | None

    @property
    def ok(self) -> bool:
        if self.value is None:
            return False
        return (self.min is None or self.value >= self.min) and (self.max is None or self.value <= self.max)

    @property
    def message(self) -> str:
        if self.value is None:
            return f"{self.kpi} is undefined in this run"
        if self.min is not None and self.value < self.min:
            return f"{self.kpi} = {self.value:.4g} is below the minimum {self.min:g} by {self.min - self.value:.4g}"
        if self.max is not None and self.value > self.max:
            return f"{self.kpi} = {self.value:.4g} is above the maximum {self.max:g} by {self.value - self.max:.4g}"
        return f"{self.kpi} = {self.value:.4g} within [{self.min}, {self.max}]"


@dataclass
class RunResult:
    """Everything a run produced; ``status`` is ``ok``, ``failed`` (then ``error`` says why) or
    ``partial`` (stopped on request, e.g. by Ctrl-C: ``error`` says when and why)."""

    scenario: Scenario
    fish: list[FishSpec]
    run: Run
    kpis: dict[str, Any]
    signals: pd.DataFrame
    expect: list[ExpectResult]
    status: str
    error: str | None
    t_end_s: float
    wall_s: float
    timings_s: dict[str, float] = field(default_factory=dict)
    drop_adjustments: list[Any] = field(default_factory=list)
    poses: dict[str, np.ndarray] | None = None
    """Body poses at 25 Hz and body outlines (see :func:`plant.sim.recorder.pose_record`), when asked for."""
    energy_watch: dict[str, float] = field(default_factory=dict)
    """The energy watch's largest rise without a source (:mod:`plant.sim.health`): J, and as a fraction
    of the allowed reserve (a blow-up is reported at 1)."""
    wiring: dict[str, Any] = field(default_factory=dict)
    """The stepping order, delayed links, conversions, setpoints and recorded variables
    (:meth:`fishfmu.scenario.wiring.Wiring.describe`)."""
    served: dict[str, Any] | None = None
    """A run served over OPC UA (``fishfmu serve``): its mode, endpoint, pacing and lateness, the values clients
    wrote."""

    @property
    def expect_ok(self) -> bool:
        return all(e.ok for e in self.expect)

    def dataset(self) -> Dataset:
        """The run as a one-run dataset in the measured-data format."""
        return Dataset(name=self.scenario.run.name, description="simulated by fishfmu", line=self.scenario.line,
                       kpi=self.scenario.kpi, runs=[self.run])
