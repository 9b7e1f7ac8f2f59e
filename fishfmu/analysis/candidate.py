"""What a candidate cause is: one unit holding everything ``fishfmu diagnose`` knows about it.

A candidate (:class:`Candidate`) is defined in its own module under :mod:`fishfmu.analysis.causes` and listed in
the registry (:data:`fishfmu.analysis.candidates.CANDIDATES`); nothing else names it.  It carries

- its **signature**: the quantity and the covariate it follows, as a test on the rows the data give
  (``test``, built on :func:`fishfmu.analysis.covariates.covariate_test`), and the runs that would decide it
  (``decides``);
- its **extension** of the model: the parameters it fits, how they are set in the plant parameters (or the drive
  FMUs'), the grid of strengths simulated and the residuals each parameter is fitted on, and its fitter
  (``fit``, one of :mod:`fishfmu.analysis.extension_fit` or its own);
- its **scenario fragment**, written from what the extension sets, so the two cannot disagree;
- how :mod:`fishfmu.analysis.synthetic` hides it in a test dataset.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import pandas as pd

from plant.sim.params import PlantParams

from fishfmu.analysis.calibrate import KNOBS, Calibration
from fishfmu.analysis.covariates import CovariateTest
from fishfmu.analysis.extension_fit import CandidateFit, FitContext
from fishfmu.analysis.fragments import plant_tables, plant_value
from fishfmu.analysis.levels import FRICTION, RIGOR

@dataclass(frozen=True)
class Terms:
    """What turning fitted values into a cause's own terms needs besides them: the model they were fitted on (the
    level responses' base for run-level effects) and each belt's typical setpoint."""

    base: PlantParams
    setpoint_mps: dict[str, float]


Group = Literal["alone", "transfers", "pairs", "pair_levels", "drops"] | None
"""Which residuals a parameter is fitted on (see :meth:`fishfmu.analysis.residuals.RunResiduals.squares`):
None all (lags of fish alone and pairs), ``alone`` lags of fish alone (the first belt's is the drop's), ``transfers``
lags of fish alone after a transfer, ``pairs`` the extra separation of close pairs, ``pair_levels`` the same as a share
of how far the pairs part, one level per run, ``drops`` the drops alone (their lags on the first belt; mucus fits
their slips, each drop dropped again alone)."""

PAIR_GROUPS = ("pairs", "pair_levels")


@dataclass(frozen=True)
class Candidate:
    """One candidate cause (see the module docstring)."""

    name: str
    description: str
    parameters: tuple[str, ...]
    """Names of the fitted values (``diagnosis.json``'s ``parameters``), in the order ``apply`` takes them."""
    unit: str
    off: float
    """The parameter value with the effect switched off."""
    grid: tuple[float, ...]
    """Values simulated when fitting (besides ``off``); the fit interpolates between them.  Empty: fitted without a
    grid of its own (through the level responses, or drive candidates from the drive residuals)."""
    bounds: tuple[float, float]
    acts_on: Literal["plant", "drive", "sensor"]
    """Plant candidates are fitted by re-simulating the runs; drive candidates from the drive residuals; sensor
    candidates (a photo-eye's latency) from the measured sensors against the tracks: the physics is not theirs, and
    a re-simulation takes their extension through its sensors' records (``edges``)."""
    apply: Callable[..., None]
    """``apply(target, *values)``: writes the values into a PlantParams (plant), a dict of parameters of every
    conveyor_drive FMU (drive) or a dict of parameters of every photo-eye of ``[line]`` (sensor)."""
    writes: tuple[str, ...]
    """What ``apply`` writes: dotted paths in ``[plant]`` (plant), drive FMU parameter names (drive) or photo-eye
    keys (sensor); the scenario fragment is these, read back after ``apply``."""
    test: Callable[[dict[str, pd.DataFrame], np.random.Generator], CovariateTest]
    """``test(rows, rng)``: its covariate test on the rows :func:`fishfmu.analysis.signatures.judge` reads
    (``drops``, ``passages``, ``drive``, ``pairs``, ``edges``, ``guides``, ``model_pairs``)."""
    decides: str
    """What runs would decide it when these cannot."""
    fit: Callable[["Candidate", FitContext], CandidateFit]
    """``fit(candidate, context)``: its extension fitted on the calibrated model, with the held-out gain."""
    groups: tuple[Group, ...] = (None,)
    """The residuals each parameter is fitted on (one per parameter)."""
    level_model: str | None = None
    """The model of :data:`fishfmu.analysis.levels.MODELS` it is fitted as (run-level effects), or None."""
    synthetic: Callable[[PlantParams, dict[str, float], float], None] | None = None
    """``synthetic(params, drive, strength)`` switches the effect on for a synthetic dataset (None: not one
    of :data:`fishfmu.analysis.synthetic.EFFECTS`)."""
    terms: Callable[[dict[str, float], "Terms"], dict[str, float]] | None = None
    """``terms(values, context)``: the fitted values in the cause's own physical terms (friction at 1 h and 48 h,
    stiffness at the peak, speed lost per 10 kg ...), what a process engineer and a benchmark's truth compare."""
    primary: str = ""
    """The one of ``terms`` that says how strong the cause is (what parameter recovery is judged on)."""
    plot: Callable[..., None] | None = None
    """``plot(ax, rows)``: its signature on a matplotlib axes, as its test reads the rows (the report's panel)."""
    explains: tuple[tuple[str, str], ...] = ()
    """The (table, covariate) pairs of the unexplained-discrepancy scan (:mod:`fishfmu.analysis.scan`) this cause
    accounts for: left out of the scan once it is named, and where its rivals are looked for."""
    edges: Callable[..., pd.DataFrame] | None = None
    """``edges(photoeyes, *values)``: a sensor candidate's extension applied to a run's photoeyes table (a
    re-simulation's: what its eyes would have reported), None for the others."""

    def __post_init__(self) -> None:
        if len(self.groups) != len(self.parameters):
            raise ValueError(f"candidate {self.name}: one fitting group per parameter")

    @property
    def simulated(self) -> bool:
        return self.acts_on == "plant"

    @property
    def needs_pairs(self) -> bool:
        """Fitted on close pairs only: simulating runs without touching fish tells nothing."""
        return all(g in PAIR_GROUPS for g in self.groups)

    def _values(self, values: Sequence[float]) -> tuple[float, ...]:
        """The values given, first parameters first (the ones left out keep the model's: a rigor strength alone
        keeps the model's timing)."""
        values = tuple(values)
        if not 1 <= len(values) <= len(self.parameters):
            raise ValueError(f"candidate {self.name}: values for {', '.join(self.parameters)}, got {len(values)}")
        return values

    def params(self, base: PlantParams, *values: float) -> PlantParams:
        """A copy of ``base`` with the values set (unchanged for a drive candidate)."""
        p = base.model_copy(deep=True)
        if self.acts_on == "plant":
            self.apply(p, *self._values(values))
        return p

    def drive_parameters(self, *values: float) -> dict[str, float]:
        """Parameters of every conveyor_drive FMU with the values set (empty for a plant or sensor candidate)."""
        drive: dict[str, float] = {}
        if self.acts_on == "drive":
            self.apply(drive, *self._values(values))
        return drive

    def photoeye_parameters(self, *values: float) -> dict[str, float]:
        """Keys of every photo-eye of ``[line]`` with the values set (empty unless a sensor candidate)."""
        eye: dict[str, float] = {}
        if self.acts_on == "sensor":
            self.apply(eye, *self._values(values))
        return eye

    def simulated_edges(self, photoeyes: pd.DataFrame, *values: float) -> pd.DataFrame:
        """A re-simulated run's photoeyes table with this candidate's extension (unchanged unless a sensor
        candidate's: the physics is the plant's, the edges are the eyes')."""
        if self.edges is None:
            return photoeyes
        return self.edges(photoeyes, *self._values(values))

    def fragment(self, values: dict[str, float], base: PlantParams) -> str:
        """The fitted values as a scenario fragment (TOML) a user can keep."""
        head = f"# fitted by fishfmu diagnose: {self.description}\n"
        v = [values[k] for k in self.parameters]
        if self.acts_on == "drive":
            drive = self.drive_parameters(*v)
            return head + "# in each conveyor_drive FMU instance:\n# [fmu.parameters]\n" + "".join(
                f"# {k} = {drive[k]:.4g}\n" for k in self.writes)
        if self.acts_on == "sensor":  # keys of array tables: pasted into each photo-eye's, not merged
            eye = self.photoeye_parameters(*v)
            return head + ("# in each photo-eye's table of [line], added to a latency_s it already has:\n"
                           "# [[line.photoeyes]]\n") + "".join(
                f"# {k} = {eye[k]:.4g}\n" for k in self.writes)
        p = self.params(base, *v)
        return head + plant_tables({path: plant_value(p, path) for path in self.writes})

    def extended_fragment(self, cal: Calibration, base: PlantParams, fit: CandidateFit) -> str:
        """The calibration and this candidate's fitted extension as one scenario fragment: every value that differs
        from ``base``."""
        if self.acts_on == "drive":  # one value per drive instance
            slip = {k[k.index("[") + 1:-1]: v for k, v in fit.values.items() if k.startswith(f"{self.writes[0]}[")}
            per_kg = {k[k.index("[") + 1:-1]: v for k, v in fit.values.items() if k.startswith("droop_per_kg[")}
            return cal.fragment(base) + f"# fitted by fishfmu diagnose: {self.description}\n" + "".join(
                f"# in the conveyor_drive FMU instance driving {c}:\n# [fmu.parameters]\n# {self.writes[0]} = {v:.4g}\n"
                + (f"# and {per_kg[c] * 1e3:.3g} mm/s lost per kg of fish on the belt (the drive FMU has no input for "
                   "the mass carried: this part is reported, not modelled)\n" if per_kg.get(c, 0.0) > 0.0 else "")
                for c, v in slip.items())
        if self.acts_on == "sensor":  # a photo-eye's table of [line]: never one the calibration writes
            return cal.fragment(base) + self.fragment(fit.values, cal.params)
        if self.level_model is None:
            p = self.params(cal.params, *[fit.values[k] for k in self.parameters])
            mine = {path: plant_value(p, path) for path in self.writes}
            calibrated = {path: value for path, (_, value) in cal.changed(base).items()}
            if not {k.rsplit(".", 1)[0] for k in mine} & {k.rsplit(".", 1)[0] for k in calibrated}:
                return cal.fragment(base) + self.fragment(fit.values, cal.params)
            # one TOML table may not be opened twice: the calibration's values and the extension's in one set
            return (f"# fitted by fishfmu diagnose on the runs {', '.join(cal.fit_runs)}: the calibrated model and "
                    f"{self.description}\n" + plant_tables(calibrated | mine) + cal.drive_fragment())
        # a run-level effect comes with its own constant levels (fitted with it), around the model the levels were
        # simulated about
        p = cal.level_base.model_copy(deep=True)
        FRICTION.apply(p, fit.values["friction_level"], 0.0)
        RIGOR.apply(p, fit.values.get("joint_stiffening", 0.0), 0.0)
        self.apply(p, *[fit.values[k] for k in self.parameters])
        paths = [path for k in KNOBS.values() for path in k.writes] + list(self.writes)
        changed = {path: plant_value(p, path) for path in dict.fromkeys(paths)
                   if plant_value(p, path) != plant_value(base, path)}
        return (f"# fitted by fishfmu diagnose on the runs {', '.join(cal.fit_runs)}: the calibrated model and "
                f"{self.description}\n" + plant_tables(changed) + cal.drive_fragment())
