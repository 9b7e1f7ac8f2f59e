"""The candidate causes ``fishfmu diagnose`` can name: a registry, one entry per cause.

Each entry (a :class:`Candidate`) is what the diagnosis needs to extend the model with a cause once it is
named (:mod:`fishfmu.analysis.signatures` names it): the parameters it fits and their values to try, how it
sets them in the plant parameters (or the drive FMUs'), which residuals each parameter is fitted on, and how
:mod:`fishfmu.analysis.synthetic` hides it in a test dataset.  The scenario fragment of a fitted value is
written from what the entry sets, so the two cannot disagree.

The identifiers are the ones ``diagnosis.json`` reports as ``cause``:

======================== ==============================================================================
``mucus_friction``       friction on belts changes with hours post mortem
``rigor_mortis``         joints stiffen and their range shrinks with rigor (hours post mortem)
``directional_friction`` friction depends on the direction the fish slips in (head or tail first)
``adhesion``             touching fish stick together
``drive_droop``          the belts slow down under load more than the drive model says (belt creep)
``none``                 no candidate explains the data clearly better than noise
======================== ==============================================================================

What every line has and nobody knows exactly (the fish-belt friction level, the joints' stiffness) is no
candidate: ``fishfmu calibrate`` fits it, as constants (:mod:`fishfmu.analysis.calibrate`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal


from plant.sim.params import PlantParams

from fishfmu.analysis.levels import rigor_limit_loss

# ---------------------------------------------------------------- what each candidate sets (fitted values)
def _mucus(p: PlantParams, gain: float, time_constant_h: float | None = None) -> None:
    p.extensions.mucus_friction.gain = gain
    if time_constant_h is not None:
        p.extensions.mucus_friction.time_constant_h = time_constant_h


def _rigor(p: PlantParams, stiffness_gain: float, peak_h: float | None = None, width_h: float | None = None) -> None:
    p.extensions.rigor_mortis.stiffness_gain = stiffness_gain
    p.extensions.rigor_mortis.limit_loss = rigor_limit_loss(stiffness_gain)
    if peak_h is not None:
        p.extensions.rigor_mortis.peak_h = peak_h
    if width_h is not None:
        p.extensions.rigor_mortis.width_h = width_h


def _adhesion(p: PlantParams, force_n: float) -> None:
    p.extensions.adhesion.force_n = force_n


def _direction(p: PlantParams, asymmetry: float) -> None:
    """Slipping head first (along the scales) x(1 - a), tail first x(1 + a), sideways unchanged."""
    p.extensions.direction_friction.head = 1.0 - asymmetry
    p.extensions.direction_friction.tail = 1.0 + asymmetry


def _belt_slip(drive: dict[str, float], belt_slip: float) -> None:
    drive["belt_slip"] = belt_slip


# ---------------------------------------------------------------- the hidden effects of synthetic datasets
# (strength 1: clearly visible; deliberately not the fitted family itself, e.g. rigor's range loss)
def _hide_mucus(p: PlantParams, drive: dict[str, float], s: float) -> None:
    p.extensions.mucus_friction.gain = 1.0 * s  # the mucus dries: friction doubles from fresh to dry


def _hide_rigor(p: PlantParams, drive: dict[str, float], s: float) -> None:
    p.extensions.rigor_mortis.stiffness_gain = 15.0 * s
    p.extensions.rigor_mortis.limit_loss = min(0.8, 0.7 * s)


def _hide_direction(p: PlantParams, drive: dict[str, float], s: float) -> None:
    p.extensions.direction_friction.head = 1.0 - 0.4 * s
    p.extensions.direction_friction.tail = 1.0 + 0.4 * s


def _hide_adhesion(p: PlantParams, drive: dict[str, float], s: float) -> None:
    p.extensions.adhesion.force_n = 6.0 * s


def _hide_droop(p: PlantParams, drive: dict[str, float], s: float) -> None:
    drive["belt_slip"] = 4e-4 * s


Group = Literal["transfers", "pairs"] | None
"""Which residuals a parameter is fitted on (see :meth:`fishfmu.analysis.diagnose.RunResiduals.squares`):
None all (lags of fish alone and pairs), ``transfers`` lags of fish alone after a transfer, ``pairs`` the
extra separation of close pairs."""


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
    """Values simulated when fitting (besides ``off``); the fit interpolates between them.  Empty: fitted without a grid of its own (through the level responses, or drive
    candidates from the drive residuals)."""
    bounds: tuple[float, float]
    acts_on: Literal["plant", "drive"]
    """Plant candidates are fitted by re-simulating the runs; drive candidates from the drive residuals."""
    apply: Callable[..., None]
    """``apply(target, *values)``: writes the values into a PlantParams (plant) or a dict of parameters of
    every conveyor_drive FMU (drive)."""
    writes: tuple[str, ...]
    """What ``apply`` writes: dotted paths in ``[plant]`` (plant) or drive FMU parameter names (drive); the
    scenario fragment is these, read back after ``apply``."""
    groups: tuple[Group, ...] = (None,)
    """The residuals each parameter is fitted on (one per parameter)."""
    level_model: str | None = None
    """The model of :data:`fishfmu.analysis.levels.MODELS` it is fitted as (run-level effects), or None."""
    synthetic: Callable[[PlantParams, dict[str, float], float], None] | None = None
    """``synthetic(params, drive, strength)`` switches the effect on for a synthetic dataset (None: not one
    of :data:`fishfmu.analysis.synthetic.EFFECTS`)."""

    def __post_init__(self) -> None:
        if len(self.groups) != len(self.parameters):
            raise ValueError(f"candidate {self.name}: one fitting group per parameter")

    @property
    def simulated(self) -> bool:
        return self.acts_on == "plant"

    @property
    def needs_pairs(self) -> bool:
        """Fitted on close pairs only: simulating runs without touching fish tells nothing."""
        return all(g == "pairs" for g in self.groups)

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
        """Parameters of every conveyor_drive FMU with the values set (empty for a plant candidate)."""
        drive: dict[str, float] = {}
        if self.acts_on == "drive":
            self.apply(drive, *self._values(values))
        return drive

    def fragment(self, values: dict[str, float], base: PlantParams) -> str:
        """The fitted values as a scenario fragment (TOML) a user can keep."""
        head = f"# fitted by fishfmu diagnose: {self.description}\n"
        v = [values[k] for k in self.parameters]
        if self.acts_on == "drive":
            drive = self.drive_parameters(*v)
            return head + "# in each conveyor_drive FMU instance:\n# [fmu.parameters]\n" + "".join(
                f"# {k} = {drive[k]:.4g}\n" for k in self.writes)
        p = self.params(base, *v)
        return head + plant_tables({path: plant_value(p, path) for path in self.writes})


def plant_value(p: PlantParams, path: str) -> float:
    """The value at a dotted path in ``[plant]`` (``friction.fish_belt``)."""
    obj = p
    for part in path.split("."):
        obj = getattr(obj, part)
    return float(obj)


def plant_tables(values: dict[str, float]) -> str:
    """Values at dotted paths in ``[plant]`` as TOML tables (``[plant.friction]`` ...), in the given order."""
    tables: dict[str, list[str]] = {}
    for path, value in values.items():
        *table, key = path.split(".")
        tables.setdefault(".".join(["plant", *table]), []).append(f"{key} = {value:.4g}\n")
    return "".join(f"[{t}]\n" + "".join(lines) for t, lines in tables.items())


CANDIDATES: dict[str, Candidate] = {c.name: c for c in (
    Candidate("mucus_friction", "relative change of belt friction once the mucus has dried, and how fast it dries",
              ("gain", "time_constant_h"), "", 0.0, (), (-0.8, 8.0), "plant", _mucus,
              ("extensions.mucus_friction.gain", "extensions.mucus_friction.time_constant_h"),
              groups=("transfers", "transfers"),
              level_model="mucus_friction", synthetic=_hide_mucus),
    Candidate("rigor_mortis", "extra joint stiffness at full rigor (x soft stiffness; range lost with it), when rigor "
              "peaks and how long it lasts", ("stiffness_gain", "peak_h", "width_h"), "x", 0.0, (), (0.0, 50.0), "plant",
              _rigor, ("extensions.rigor_mortis.stiffness_gain", "extensions.rigor_mortis.limit_loss",
                       "extensions.rigor_mortis.peak_h", "extensions.rigor_mortis.width_h"),
              groups=("transfers", "transfers", "transfers"),
              level_model="rigor_mortis", synthetic=_hide_rigor),
    Candidate("directional_friction", "fish-belt friction by slip direction: head first x(1 - a), tail first "
              "x(1 + a)", ("asymmetry",), "", 0.0, (0.25, 0.5), (-0.75, 0.75), "plant", _direction,
              ("extensions.direction_friction.head", "extensions.direction_friction.tail"), groups=("transfers",),
              synthetic=_hide_direction),
    Candidate("adhesion", "attraction per pair of touching contact spheres", ("force_n",), "N",
              0.0, (2.0, 6.0), (0.0, 50.0), "plant", _adhesion, ("extensions.adhesion.force_n",),
              groups=("pairs",), synthetic=_hide_adhesion),
    Candidate("drive_droop", "belt creep on its drum: belt speed drop per newton of load", ("belt_slip",), "(m/s)/N",
              0.0, (), (0.0, 0.01), "drive", _belt_slip, ("belt_slip",), synthetic=_hide_droop),
)}


def fragment(name: str, values: dict[str, float], base: PlantParams) -> str:
    """The fitted extension as a scenario fragment (TOML) a user can keep ("none": says there is none)."""
    if name not in CANDIDATES:
        return "# no extension: no candidate explains the data clearly better than noise\n"
    return CANDIDATES[name].fragment(values, base)
