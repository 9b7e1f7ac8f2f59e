"""Before a run: every FMU described once, its parameters checked, the wiring resolved.

One check for every way a scenario is run (``fishfmu run``, ``run --seeds``, each point of a
``sweep``, :func:`fishfmu.cosim.runner.run_scenario` from a script), so that what is bad input is the same
everywhere and is found before anything is written: a parameter the FMU does not have, one that is
not settable or of the wrong type, a value outside the range its modelDescription declares, and
every connection, constant input and event target of the wiring.

An :class:`FmuDescription` comes from an unpacked, checked archive (:func:`describe`, used by a run)
or from the modelDescription alone (:func:`describe_file`, enough for a sweep to check its points
without unpacking every FMU once per point).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from plant.errors import InputError

from fishfmu.fmu.archive import FmuVariable, variables_of
from fishfmu.fmu.instance import check_parameters
from fishfmu.scenario.schema import Scenario
from fishfmu.scenario.wiring import Wiring, direct_feedthrough, resolve_wiring


@dataclass(frozen=True)
class FmuDescription:
    """What the checks need to know of one FMU file."""

    path: Path
    variables: dict[str, FmuVariable]
    ranges: dict[str, tuple[Any, Any]]
    """Declared (min, max) per variable; None where the modelDescription gives none."""
    feedthrough: set[str]
    """Outputs declared to depend directly on an input (see :func:`fishfmu.scenario.wiring.direct_feedthrough`)."""


def describe(path: str | Path, model_description: Any, variables: dict[str, FmuVariable]) -> FmuDescription:
    """The description of an FMU from its (already read and checked) modelDescription."""
    ranges = {v.name: (v.min, v.max) for v in model_description.modelVariables}
    return FmuDescription(Path(path), variables, ranges, direct_feedthrough(model_description))


def describe_file(path: str | Path) -> FmuDescription:
    """The description of an FMU read from its modelDescription alone (no unpacking, no binary)."""
    from fmpy import read_model_description
    try:
        md = read_model_description(str(path))
    except Exception as exc:  # fmpy raises what the XML parser or zipfile raise
        raise InputError(f"cannot read the FMU's modelDescription: {exc}", file=path) from None
    return describe(path, md, variables_of(md))


def preflight(scenario: Scenario, scenario_file: str | Path | None,
              fmus: Mapping[str, FmuDescription]) -> Wiring:
    """Check every FMU's parameters (name, causality, type, declared range) and resolve the wiring;
    raises InputError naming the scenario file and the key."""
    sfile = str(scenario_file) if scenario_file else None
    for i, f in enumerate(scenario.fmu):
        described = fmus[f.name]
        entry = f.origin or f"fmu[{i}]"  # an FMU brought in by [system] ssp is named by its component
        check_parameters(f.name, described, f.parameters, sfile, entry)
        for key, value in f.parameters.items():
            lo, hi = described.ranges.get(key, (None, None))
            if isinstance(value, (int, float)) and not isinstance(value, bool) and (
                    (lo is not None and value < float(lo)) or (hi is not None and value > float(hi))):
                raise InputError(f"{key} = {value} is outside the range [{lo}, {hi}] that FMU '{f.name}' declares",
                                 file=sfile or described.path, where=f"{entry}.parameters.{key}")
        for key, unit in f.stated_units.items():  # a parameter file's stated unit must be the variable's
            var = described.variables[key]
            if var.unit and unit != var.unit:
                raise InputError(f"the parameter file gives '{key}' in {unit} but FMU '{f.name}' has it in "
                                 f"{var.unit}; give the value in {var.unit}", file=sfile or described.path,
                                 where=f"{entry}.parameters.{key}")
    return resolve_wiring(scenario, {n: d.variables for n, d in fmus.items()}, sfile,
                          {n: d.feedthrough for n, d in fmus.items()})
