"""The candidate causes ``fishfmu diagnose`` can name: the registry, one entry per cause.

Each cause is one unit in its own module (:mod:`fishfmu.analysis.causes`; what a unit holds:
:class:`fishfmu.analysis.candidate.Candidate`); adding one is its module and a line here.  The order is the order
the covariate tests are run in (they draw from one random stream, so it is part of a diagnosis's result).

The identifiers are the ones ``diagnosis.json`` reports as ``cause``:

======================== ==============================================================================
``mucus_friction``       friction on belts changes with hours post mortem
``rigor_mortis``         joints stiffen and their range shrinks with rigor (hours post mortem)
``directional_friction`` friction depends on the direction the fish slips in (head or tail first)
``drive_droop``          the belts slow down under load more than the drive model says (belt creep)
``adhesion``             touching fish stick together
``photoeye_latency``     the photo-eyes report their edges late (a sensor at fault: a slow input card, a filter)
``guide_wear``           fish-guide friction rises along the line (guide liners grip harder downstream)
``none``                 no candidate explains the data clearly better than noise
======================== ==============================================================================

What every line has and nobody knows exactly (the fish-belt friction level, the joints' stiffness) is no
candidate: ``fishfmu calibrate`` fits it, as constants (:mod:`fishfmu.analysis.calibrate`).
"""

from __future__ import annotations

from plant.sim.params import PlantParams

from fishfmu.analysis.candidate import Candidate
from fishfmu.analysis.causes import adhesion, directional, droop, guide, latency, mucus, rigor

CANDIDATES: dict[str, Candidate] = {m.CANDIDATE.name: m.CANDIDATE for m in (mucus, rigor, directional, droop, adhesion,
                                                                               latency, guide)}


def fragment(name: str, values: dict[str, float], base: PlantParams) -> str:
    """The fitted extension as a scenario fragment (TOML) a user can keep ("none": says there is none)."""
    if name not in CANDIDATES:
        return "# no extension: no candidate explains the data clearly better than noise\n"
    return CANDIDATES[name].fragment(values, base)
