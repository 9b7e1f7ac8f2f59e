"""Physical and numerical parameters of the plant, each with where its default comes from.

This is the ``[plant]`` table of a scenario file.  Two kinds of numbers live here:

- physical ones (friction coefficients, joint behaviour, guide height): from the paper where it
  has them, otherwise an assumption named in the field's description;
- numerical ones (integration step, contact and joint stiffness expressed as frequencies,
  friction regularisation).  The fish is integrated explicitly (Exudyn's VelocityVerlet, one
  force evaluation per step), so every spring is chosen from the mass or inertia it acts on:
  a stiffness ``k = m * omega**2`` with a target frequency ``omega`` that the step can carry
  (``omega * step_s`` well below 2).  Contact stiffness then means "a resting fish sinks
  ``g / omega**2`` (about 1 mm) into the belt", which is what dead salmon flesh does.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from plant.fish.extensions import Extensions
from plant.validation import Strict


class FrictionParams(Strict):
    """Coulomb friction coefficients (regularised, see ``NumericsParams.friction_regularization_mps``)."""

    fish_belt: float = Field(0.45, ge=0.0, le=2.0, description=(
        "wet salmon skin on a PU/PVC food belt; reported values 0.3-0.6 (assumption: mid-range)"))
    fish_fish: float = Field(0.30, ge=0.0, le=2.0, description=(
        "salmon on salmon, both covered in mucus (assumption; lower than on a belt)"))
    fish_guide: float = Field(0.25, ge=0.0, le=2.0, description="salmon on polished stainless side guides (assumption)")
    belt_gradient: float = Field(0.0, ge=-0.8, le=0.8, description=(
        "fish-belt (and guide) friction along the fish: the head body takes (1 - g), the fin (1 + g) times the "
        "fish's coefficient, linearly between (skin, scales and mucus differ along a salmon); g > 0 grips more "
        "at the tail, so a fish taken over by a faster belt head first comes up to speed later than without it, one "
        "tail first sooner"))


class JointParams(Strict):
    """The rag-doll joints: soft inside the paper's limits (Table III), stiffening smoothly at them."""

    sag_fraction: float = Field(0.5, gt=0.05, le=1.0, description=(
        "fraction of its bending limit that the lighter side of a joint sags under its own weight "
        "when the fish is held horizontally (the paper measured bending (Fig. 4) but gives no numbers; "
        "assumption for a limp, pre-rigor fish)"))
    limit_transition: float = Field(0.15, gt=0.0, le=0.5, description=(
        "half-width of the zone around each limit over which the stiffness rises, as a fraction of the limit"))
    damping_ratio: float = Field(0.3, ge=0.0, le=1.0, description=(
        "rotational damping of the joints relative to critical: the paper's 'angular drag' that stands "
        "for tissue around the joints"))
    locked_twist_deg: float = Field(2.0, gt=0.0, le=10.0, description=(
        "Table III gives twist limit 0 for joints 1-3 (locked); a spring cannot be exactly rigid, so these "
        "twist this far at most under load"))
    limit_scale: float = Field(1.0, gt=0.1, le=5.0, description=(
        "multiplies every bending and twist limit of Table III (1 = the paper's fish)"))
    stiffness_scale: float = Field(1.0, gt=0.01, le=100.0, description=(
        "multiplies the soft stiffness inside the limits (1 = the sag rule above)"))
    stiffening: float = Field(0.0, ge=0.0, le=50.0, description=(
        "every fish's joints this much stiffer (x the soft stiffness, added to rigor's), losing the range that "
        "goes with it by rigor's law (limits x (1 - 0.6 s / (s + 3))): for a line whose fish bend less than "
        "the paper's at any age; fitted by fishfmu diagnose's calibration"))


FISH_NUMERICS = {"joined4": {"step_s": 0.002, "sphere_spacing": 3.0, "search_cell_m": 0.3},
                 "paper5": {"step_s": 0.00125, "sphere_spacing": 2.0, "search_cell_m": 0.1}}
"""The explicit step, the spheres' spacing and the contact search's cells each fish model (``plant.fish_model``) was
checked at (50 seeded dumps, no body through a belt); used where a scenario does not set them.  0.3 m cells against
0.1 m took Exudyn's time a step down 6 % on the dumped batch and 18 % on the continuous line with the joined fish
(docs/performance.md, 2026-11-30).  The paper's fish keeps 0.1 m cells: coarser ones measured no faster with it,
and they change every run in its last bits, which moved a borderline answer of ``diagnose`` (whose benchmark was
measured with that fish and those cells)."""


class NumericsParams(Strict):
    """Integration and penalty settings; they decide speed and stability, not the physics."""

    step_s: float = Field(0.002, gt=1e-5, le=0.01, description=(
        "explicit integration step (VelocityVerlet, one force evaluation per step); when not given, the fish "
        "model's own: 2 ms for 'joined4' (0 of 50 seeded dumps put a body through a belt), 1.25 ms for 'paper5' "
        "(its tail fin under a pile dips through the belt at 1.67 ms and above)"))
    contact_omega_rad_s: float = Field(300.0, gt=10.0, le=2000.0, description=(
        "contact stiffness of every sphere of a fish = fish mass / number of its spheres x omega^2: a "
        "resting fish sinks about 0.2 mm into the belt; a fish falling onto another stops within a "
        "sphere radius (softer springs let the snout or fin of a fish under a pile be pushed through "
        "the belt; stiffer ones need a smaller step)"))
    contact_damping_ratio: float = Field(0.1, ge=0.0, le=1.0, description=(
        "normal contact damping relative to critical, per sphere; Exudyn adds the dampers of two touching "
        "spheres, so a heavy body's damper acts on a light fin: keep this low for stability"))
    joint_translation_omega_rad_s: float = Field(150.0, gt=10.0, le=2000.0, description=(
        "stiffness of the translational coupling at each joint = reduced mass x omega^2 (about 1 mm of "
        "stretch under 10 N for a 2 kg fish)"))
    joint_limit_omega_rad_s: float = Field(250.0, gt=10.0, le=2000.0, description=(
        "rotational stiffness beyond a joint limit (and of the locked twist of joints 1-3) = the two "
        "bodies' reduced inertia about their centres of mass x omega^2"))
    friction_regularization_mps: float = Field(0.03, gt=1e-4, le=0.5, description=(
        "slip speed below which Coulomb friction is proportional to slip (GeneralContact's proportional "
        "zone); it must exceed ~10 x mu g step_s for the explicit step to stay stable under piles"))
    sphere_spacing: float = Field(3.0, ge=1.0, le=4.0, description=(
        "distance between contact spheres along the fish, in sphere radii (2 = touching); when not given, the "
        "fish model's own: 3 for 'joined4', 2 for 'paper5'"))
    search_cell_m: float = Field(0.3, ge=0.02, le=2.0, description=(
        "edge of the cells of the contact search grid (Exudyn's general contact sorts every sphere into them each "
        "step and empties every cell first, so small cells over the line's search box cost time; they decide "
        "speed and the order in which contacts are summed, not which contacts act); when not given, the fish "
        "model's own: 0.3 m for 'joined4', 0.1 m for 'paper5'"))
    min_body_mass_fraction: float = Field(0.06, ge=0.0, le=0.2, description=(
        "mass scaling, as explicit crash codes do: the paper's tail fin (2.2 %, Table II) is raised to this "
        "share of the fish, taken from the tail body, so that contact springs stiff enough to stop the fin "
        "under a falling fish fit the step; fish mass and length are unchanged, the centre of mass moves "
        "about 4 mm towards the tail"))
    inertia_shaping: bool = Field(True, description=(
        "raise the rotational inertia of thin bodies (the tail fin) to what their contact spheres need for "
        "a stable step; adds inertia, never mass"))
    threads: int = Field(1, ge=1, le=64, description=(
        "Exudyn worker threads; with more than 1 a run is not reproducible (the contact forces are summed in an "
        "order that changes from run to run, and a pile of fish makes the difference grow): for serving a PLC "
        "in real time, not for results"))


class PlantParams(Strict):
    """Everything the plant needs beyond the line and the fish."""

    fish_model: Literal["joined4", "paper5"] = Field("joined4", description=(
        "the fish's rigid bodies: 'joined4' (the default) four, the paper's cuts with the tail fin joined rigidly "
        "to the tail (the fin bends little against the tail at the scale of a belt and its gaps; tail and fin "
        "carry the paper's 22.8 % together, no mass floor; joints 1-3 of Table III unchanged, the tail-fin joint "
        "gone), thin bodies' inertia raised to the full value their spheres imply, integrated at 2 ms with "
        "spheres three radii apart; 'paper5' the paper's five (head, upper body, lower body, tail, tail fin; the "
        "fin raised to numerics.min_body_mass_fraction of the mass), integrated at 1.25 ms with touching spheres "
        "(docs/model.md, 'The joined fish')"))
    friction: FrictionParams = Field(default_factory=FrictionParams)
    joints: JointParams = Field(default_factory=JointParams)
    numerics: NumericsParams = Field(default_factory=NumericsParams)
    guide_height_m: float = Field(0.30, gt=0.02, le=2.0, description="height of the side guides above the belt (assumption)")
    gravity_mps2: float = Field(9.81, ge=0.0, le=20.0, description="gravitational acceleration (standard gravity)")
    incline_deg: float = Field(0.0, ge=-45.0, le=45.0, description=(
        "tilts gravity about y (positive: the line rises downstream), for incline tests and inclined lines"))
    extensions: Extensions = Field(default_factory=Extensions, description=(
        "effects beyond the paper's model (direction-dependent and mucus friction, rigor mortis, adhesion); "
        "all off by default, see plant.fish.extensions"))
    retire_after_m: float = Field(0.3, ge=0.0, le=5.0, description=(
        "a fish whose every body is this far beyond the end of the last conveyor has left the line and is "
        "taken out of the simulation"))

    @model_validator(mode="after")
    def _numerics_of_the_fish(self) -> "PlantParams":
        # The step and the spheres' spacing a fish model was checked at are part of that model: choosing the
        # paper's fish alone gives the paper's fish as it was measured, not its bodies at the joined one's step.
        for key, value in FISH_NUMERICS[self.fish_model].items():
            if key not in self.numerics.model_fields_set:
                setattr(self.numerics, key, value)
                self.numerics.model_fields_set.discard(key)
        return self
