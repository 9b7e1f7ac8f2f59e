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

import zipfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fmpy import read_model_description

from plant.errors import InputError

from fishfmu.fmu.archive import (MAX_MEMBERS, MAX_UNPACKED_BYTES, FmuVariable, check_members, open_regular_file,
                                 variables_of)
from fishfmu.fmu.instance import check_parameters
from fishfmu.scenario.keys import dotted_parts
from fishfmu.scenario.schema import Scenario
from fishfmu.scenario.order import direct_feedthrough
from fishfmu.scenario.wiring import Wiring, resolve_wiring


@dataclass(frozen=True)
class FmuDescription:
    """What the checks need to know of one FMU file."""

    path: Path
    variables: dict[str, FmuVariable]
    ranges: dict[str, tuple[Any, Any]]
    """Declared (min, max) per variable; None where the modelDescription gives none."""
    feedthrough: set[str]
    """Outputs declared to depend directly on an input (see :func:`fishfmu.scenario.order.direct_feedthrough`)."""


def describe(path: str | Path, model_description: Any, variables: dict[str, FmuVariable]) -> FmuDescription:
    """The description of an FMU from its (already read and checked) modelDescription."""
    ranges = {v.name: (v.min, v.max) for v in model_description.modelVariables}
    return FmuDescription(Path(path), variables, ranges, direct_feedthrough(model_description))


def describe_file(path: str | Path) -> FmuDescription:
    """The description of an FMU read from its modelDescription alone (no unpacking, no binary).

    The file is checked as :func:`~fishfmu.fmu.archive.open_fmu` checks it before a byte is read (a regular
    file, not a FIFO or device) and the archive's directory before its modelDescription is read."""
    with open_regular_file(Path(path)) as fh:
        try:
            with zipfile.ZipFile(fh) as zf:
                check_members(Path(path), zf, MAX_UNPACKED_BYTES, MAX_MEMBERS)
            fh.seek(0)
            md = read_model_description(fh)
        except InputError:
            raise
        except Exception as exc:  # fmpy raises what the XML parser or zipfile raise
            raise InputError(f"cannot read the FMU's modelDescription: {exc}", file=path) from None
    return describe(path, md, variables_of(md))


def preflight_changes(keys: Iterable[str]) -> set[int] | None:
    """What :func:`preflight` must check again in a scenario that passed it once and was then changed at these
    dotted keys (a sweep's point): None for everything; else the indices of the ``[[fmu]]`` entries whose start
    values alone changed (an empty set: nothing).

    It follows what preflight reads: the FMUs (their files, names, parameters and parameter files), the SSP,
    the wiring, ``[opcua]``, ``[[event]]``, ``[record]``, ``[expect]``, the line's ids and ``run.coupling``;
    not ``[fish]``, ``[plant]``, ``[kpi]``, the rest of ``[run]`` or an FMU's ``step_multiple``.  A key it
    does not know is taken as changing everything.

    >>> preflight_changes(["fish.count", "run.duration_s", "fmu[2].step_multiple"])
    set()
    >>> preflight_changes(["fmu[0].parameters.speed_1", "fmu[3].parameter_file"])
    {0, 3}
    >>> preflight_changes(["run.coupling"]) is None, preflight_changes(["wiring.inputs"]) is None
    (True, True)
    """
    start_values: set[int] = set()
    for key in keys:
        parts = dotted_parts(key)
        top = parts[0] if parts else ""
        if top in ("fish", "plant", "kpi"):
            continue
        if top == "run" and len(parts) > 1 and parts[1] != "coupling":
            continue
        if top == "fmu" and len(parts) > 2 and isinstance(parts[1], int):
            if parts[2] == "step_multiple":
                continue
            if parts[2] in ("parameters", "parameter_file"):
                start_values.add(parts[1])
                continue
        return None
    return start_values


def check_start_values(scenario: Scenario, scenario_file: str | Path | None, fmus: Mapping[str, FmuDescription],
                       indices: Iterable[int] | None = None) -> None:
    """Check the start values of every FMU (or those of the ``[[fmu]]`` entries at ``indices``): name, causality,
    type, declared range and a parameter file's stated units; raises InputError naming the scenario file and key."""
    sfile = str(scenario_file) if scenario_file else None
    for i in range(len(scenario.fmu)) if indices is None else sorted(indices):
        f = scenario.fmu[i]
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


def preflight(scenario: Scenario, scenario_file: str | Path | None,
              fmus: Mapping[str, FmuDescription]) -> Wiring:
    """Check every FMU's parameters (name, causality, type, declared range) and resolve the wiring;
    raises InputError naming the scenario file and the key."""
    check_start_values(scenario, scenario_file, fmus)
    sfile = str(scenario_file) if scenario_file else None
    return resolve_wiring(scenario, {n: d.variables for n, d in fmus.items()}, sfile,
                          {n: d.feedthrough for n, d in fmus.items()})
