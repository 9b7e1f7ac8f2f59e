"""The candidate causes ``fishfmu diagnose`` can name: each a parameterised model extension.

A candidate knows how to set its strength in the plant parameters (or the drive), which values to
try when fitting, and how to write a fitted value as a scenario fragment.  The identifiers are the
ones ``diagnosis.json`` reports as ``cause``:

================== ====================================================================================
``belt_friction``  the fish-belt friction coefficient is off (a calibration, not a new effect)
``direction_friction`` friction depends on the direction a fish slips: head first, tail first, across
``mucus_friction`` friction on belts changes with hours post mortem
``rigor_mortis``   joints stiffen and their range shrinks with rigor (hours post mortem)
``adhesion``       touching fish stick together
``drive_droop``    the belts slow down under load more than the drive model says (belt creep)
``none``           no candidate explains the data clearly better than noise
================== ====================================================================================
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from plant.params import PlantParams


def _belt_friction(p: PlantParams, v: float) -> None:
    p.friction.fish_belt = p.friction.fish_belt * v


def _direction(p: PlantParams, head: float, tail: float | None = None) -> None:
    d = p.extensions.direction_friction
    d.head, d.tail = head, head if tail is None else tail
    d.across = 0.5 * (d.head + d.tail)


def _mucus(p: PlantParams, v: float) -> None:
    p.extensions.mucus_friction.gain = v


def _rigor(p: PlantParams, v: float) -> None:
    # one strength for both effects of rigor: stiffness x (1 + v) at full rigor, range shrinking with it
    p.extensions.rigor_mortis.stiffness_gain = v
    p.extensions.rigor_mortis.limit_loss = 0.6 * v / (v + 3.0)


def _adhesion(p: PlantParams, v: float) -> None:
    p.extensions.adhesion.force_n = v


@dataclass(frozen=True)
class Candidate:
    name: str
    description: str
    off: float
    """The parameter value with the effect switched off."""
    grid: tuple[float, ...]
    """Values simulated when fitting (besides ``off``); the fit interpolates between them."""
    apply: Callable[..., None] | None
    """Sets the strength in a PlantParams (None: not a plant effect)."""
    unit: str
    bounds: tuple[float, float]

    def params(self, base: PlantParams, *values: float) -> PlantParams:
        p = base.model_copy(deep=True)
        if self.apply is not None:
            self.apply(p, *values)
        return p


CANDIDATES: dict[str, Candidate] = {c.name: c for c in (
    Candidate("belt_friction", "fish-belt friction coefficient (multiplier of the model's)", 1.0,
              (0.7, 0.85, 1.15, 1.35), _belt_friction, "x", (0.3, 3.0)),
    Candidate("direction_friction", "friction multipliers when slipping head first / tail first", 1.0,
              (0.6, 0.8, 1.25, 1.6), _direction, "x", (0.21, 2.9)),
    Candidate("mucus_friction", "relative change of belt friction once the mucus has dried", 0.0,
              (-0.4, -0.2, 0.2, 0.4), _mucus, "", (-0.8, 2.0)),
    Candidate("rigor_mortis", "extra joint stiffness at full rigor (x soft stiffness; range lost with it)", 0.0,
              (2.0, 5.0, 12.0), _rigor, "x", (0.0, 50.0)),
    Candidate("adhesion", "attraction per pair of touching contact spheres", 0.0,
              (1.0, 3.0, 8.0), _adhesion, "N", (0.0, 50.0)),
    Candidate("drive_droop", "belt creep on its drum: belt speed drop per newton of load", 0.0,
              (), None, "(m/s)/N", (0.0, 0.01)),
)}


def fragment(name: str, values: dict[str, float], base: PlantParams) -> str:
    """The fitted extension as a scenario fragment (TOML) a user can keep."""
    if name not in CANDIDATES:
        return "# no extension: no candidate explains the data clearly better than noise\n"
    head = f"# fitted by fishfmu diagnose: {CANDIDATES[name].description}\n"
    if name == "belt_friction":
        return head + f"[plant.friction]\nfish_belt = {base.friction.fish_belt * values['multiplier']:.4g}\n"
    if name == "direction_friction":
        h, t = values["head"], values["tail"]
        return head + (f"[plant.extensions.direction_friction]\nhead = {h:.4g}\ntail = {t:.4g}\n"
                       f"across = {0.5 * (h + t):.4g}\n")
    if name == "mucus_friction":
        return head + f"[plant.extensions.mucus_friction]\ngain = {values['gain']:.4g}\n"
    if name == "rigor_mortis":
        v = values["stiffness_gain"]
        return head + (f"[plant.extensions.rigor_mortis]\nstiffness_gain = {v:.4g}\n"
                       f"limit_loss = {0.6 * v / (v + 3.0):.4g}\n")
    if name == "adhesion":
        return head + f"[plant.extensions.adhesion]\nforce_n = {values['force_n']:.4g}\n"
    if name == "drive_droop":
        return head + ("# in each conveyor_drive FMU instance:\n# [fmu.parameters]\n"
                       f"# belt_slip = {values['belt_slip']:.4g}\n")
    raise AssertionError(name)


PARAMETER_NAMES = {"belt_friction": ("multiplier",), "direction_friction": ("head", "tail"),
                   "mucus_friction": ("gain",), "rigor_mortis": ("stiffness_gain",), "adhesion": ("force_n",),
                   "drive_droop": ("belt_slip",)}
