"""What a sweep runs: its definition (every combination of the swept values, the seeds, ``--set`` and ``--scale``),
the values of ``--param``, the limit on its size, the ids of its runs, and each point checked before any run
(:class:`PointPreparer`).  Running it: :mod:`fishfmu.batch.sweep`.

>>> parse_param("fmu[0].parameters.speed_2=0.4,0.5")
('fmu[0].parameters.speed_2', [0.4, 0.5])
>>> parse_param("fish.length_mean_m=0.5:0.7:3")
('fish.length_mean_m', [0.5, 0.6, 0.7])
>>> parse_param("fish.count=10:30:3")
('fish.count', [10, 20, 30])
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from plant.contract.parts import part_triangles
from plant.errors import MAX_ECHO_CHARS, InputError, capped
from plant.validation import read_toml

from fishfmu.cosim.preflight import FmuDescription, check_start_values, describe_file, preflight, preflight_changes
from fishfmu.scenario.keys import dotted_parts, get_dotted, parse_value
from fishfmu.scenario.schema import RunSettings, Scenario, ScenarioLoader, load_scenario

MAX_RUNS = 100_000
"""Runs in one sweep (points x seeds), and so values of one range: a run takes seconds to minutes of a
core (the paper test: about 10 s), so 100 000 runs are days of a 64-core cluster, and the sweep's
folder holds a file per run.  Larger sweeps are refused before anything is allocated."""
FORMAT = 1
MAX_SEED: int = next(m.le for m in RunSettings.model_fields["seed"].metadata if hasattr(m, "le"))
"""The largest ``run.seed`` (the schema's bound): a sweep's last seed must not pass it."""
_RANGE = re.compile(r"^\s*([-+]?[\d.eE+-]+)\s*:\s*([-+]?[\d.eE+-]+)\s*:\s*(\d+)\s*$")


# ---------------------------------------------------------------- the definition

@dataclass(frozen=True)
class SweepSpec:
    """What a sweep runs; ``parameters`` keeps the order given (the first varies slowest)."""

    scenario: str
    """absolute path of the scenario file"""
    parameters: dict[str, list[Any]]
    seeds: list[int]
    fixed: dict[str, Any] = field(default_factory=dict)
    """overrides applied at every point (``--set``)"""
    scales: dict[str, list[str]] = field(default_factory=dict)
    """named factors (``--scale NAME=KEY1,KEY2``): a swept NAME multiplies the scenario's value of each KEY
    (the belt speeds of a profile, scaled together)"""

    def definition(self) -> dict[str, Any]:
        """sweep.json: everything that decides the runs' results (the scenario file by its content too)."""
        return {"format": FORMAT, "scenario": self.scenario,
                "scenario_sha256": hashlib.sha256(Path(self.scenario).read_bytes()).hexdigest(),
                "fixed": self.fixed, "parameters": [[k, v] for k, v in self.parameters.items()], "seeds": self.seeds,
                **({"scales": self.scales} if self.scales else {})}

    def points(self) -> list[dict[str, Any]]:
        keys = list(self.parameters)
        return [dict(zip(keys, combo)) for combo in itertools.product(*self.parameters.values())]


def make_spec(scenario: str | Path, parameters: dict[str, list[Any]], n_seeds: int,
              fixed: dict[str, Any] | None = None, scales: dict[str, list[str]] | None = None) -> SweepSpec:
    """Check the sweep as a whole (the scenario with ``fixed`` must load) and choose the seeds."""
    fixed = dict(fixed or {})
    scales = {k: list(v) for k, v in (scales or {}).items()}
    for name, keys in scales.items():
        if name not in parameters:
            raise InputError(f"--scale {name}: not swept (give its factors with --param {name}=...)")
        if not keys:
            raise InputError(f"--scale {name}: no keys to scale")
        for key in keys:
            if key in parameters or key in fixed:
                raise InputError(f"--scale {name}: '{key}' is also swept or fixed (--param/--set)")
            value = get_dotted(read_toml(Path(scenario)), key, fixed)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise InputError(f"--scale {name}: '{key}' is {value!r} in the scenario, not a number to scale")
    if n_seeds < 1:
        raise InputError(f"--seeds must be at least 1 (got {n_seeds})")
    check_size(math.prod(len(v) for v in parameters.values()), n_seeds)
    for key, values in parameters.items():
        if key == "run.seed":
            raise InputError("sweep the seed with --seeds N, not as a parameter")
        if not values:
            raise InputError(f"parameter '{key}' has no values")
        if key in fixed:
            raise InputError(f"'{key}' is both swept and fixed (--set)")
    base = load_scenario(scenario, fixed)
    part_triangles(base.line)  # a part's STL file refused before the sweep's folder is made, not in every run
    first = base.run.seed
    if first + n_seeds - 1 > MAX_SEED:
        raise InputError(f"--seeds {n_seeds}: the seeds run from run.seed = {first} to {first + n_seeds - 1}, past "
                         f"the largest seed ({MAX_SEED})")
    spec = SweepSpec(str(Path(scenario).resolve()), {k: list(v) for k, v in parameters.items()},
                     list(range(first, first + n_seeds)), fixed, scales)
    preparer = PointPreparer(spec)
    for key, values in spec.parameters.items():  # a key no value works for is a typo, not a failed point
        first_error = None
        for v in values:  # until one works: the points themselves are prepared once, when the sweep runs
            try:
                preparer.prepare({key: v})
                break
            except InputError as exc:
                first_error = first_error or exc
        else:
            raise InputError(f"--param {key}: no value works: {first_error}")
    return spec


def _split_top_level(text: str) -> list[str]:
    """Split at commas outside brackets and quotes (values may be TOML arrays or strings)."""
    parts, depth, quote, current = [], 0, "", ""
    for ch in text:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(current)
            current = ""
            continue
        current += ch
    return [p.strip() for p in parts + [current]]


def parse_param(text: str) -> tuple[str, list[Any]]:
    """``KEY=V1,V2,...`` or ``KEY=START:STOP:N`` (N evenly spaced values, ends included)."""
    key, eq, values = text.partition("=")
    key = key.strip()
    text = capped(text, MAX_ECHO_CHARS)  # only echoed below: the reason must fit in a message's first 1000 characters
    if not eq or not key or not values.strip():
        raise InputError(f"--param '{text}': expected KEY=V1,V2,... or KEY=START:STOP:N")
    m = _RANGE.match(values)
    if m:
        if len(m.group(3).lstrip("0")) > len(str(MAX_RUNS)) or int(m.group(3)) > MAX_RUNS:
            raise InputError(f"--param '{text}': a range may have at most {MAX_RUNS} values (runs in a sweep: "
                             f"at most {MAX_RUNS}, points x seeds)")
        try:
            start, stop, n = float(m.group(1)), float(m.group(2)), int(m.group(3))
        except ValueError:
            raise InputError(f"--param '{text}': START and STOP of a range must be numbers") from None
        if n < 1:
            raise InputError(f"--param '{text}': a range needs at least one value")
        if not (math.isfinite(start) and math.isfinite(stop)):
            raise InputError(f"--param '{text}': START and STOP must be finite numbers (not NaN or inf)")
        ints = m.group(1).lstrip("+-").isdigit() and m.group(2).lstrip("+-").isdigit()
        grid = np.linspace(start, stop, n)
        if ints and np.allclose(grid, np.round(grid)):
            return key, [int(round(v)) for v in grid]
        return key, [float(f"{v:.12g}") for v in grid]  # 0.3, not 0.30000000000000004
    parsed = [parse_value(v) for v in _split_top_level(values)]
    if any(v == "" for v in parsed):
        raise InputError(f"--param '{text}': empty value")
    if len(parsed) > MAX_RUNS:
        raise InputError(f"--param '{text}': at most {MAX_RUNS} values (runs in a sweep: at most {MAX_RUNS})")
    if any(not _finite(v) for v in parsed):
        raise InputError(f"--param '{text}': NaN and inf are not values a scenario can take")
    return key, parsed


def _finite(value: Any) -> bool:
    """False for NaN or inf anywhere in a value (numbers, arrays, tables)."""
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, float) and not math.isfinite(v):
            return False
        if isinstance(v, (list, tuple)):
            stack.extend(v)
        elif isinstance(v, dict):
            stack.extend(v.values())
    return True


def check_size(n_points: int, n_seeds: int) -> None:
    """Refuse a sweep of more than :data:`MAX_RUNS` runs (before anything is allocated for it)."""
    if n_seeds > MAX_RUNS or n_points * n_seeds > MAX_RUNS:
        raise InputError(f"{n_points} point(s) x {n_seeds} seed(s) = {n_points * n_seeds} runs; a sweep may have at "
                         f"most {MAX_RUNS} runs (split it, or sweep fewer values)")


def run_id(params: dict[str, Any], seed: int | None = None) -> str:
    """A stable id of a point (and seed): the same values give the same id in any process."""
    text = json.dumps({"params": params, "seed": seed}, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# ---------------------------------------------------------------- checking points up front

class PointPreparer:
    """Validates the points of one sweep before any run, paying per point only for what differs between points.

    Once per sweep: the scenario file, its parameter files and SSP are read (:class:`ScenarioLoader`), each FMU's
    modelDescription is read, and the base scenario (with ``--set``) has its FMU start values and wiring checked
    (:func:`fishfmu.cosim.preflight.preflight`).  Per point: the scenario with the point's overrides is validated
    whole (pydantic: the cross-field checks too, a fraction of a millisecond), then preflight checks only what
    the overrides can change (:func:`fishfmu.cosim.preflight.preflight_changes`): nothing for ``[fish]``,
    ``[plant]`` or ``run.duration_s``, one FMU's start values for ``fmu[i].parameters.*``, everything for a key
    of the wiring.  Where the base itself fails preflight, every point is checked in full."""

    def __init__(self, spec: SweepSpec) -> None:
        self.spec = spec
        self.loader = ScenarioLoader(spec.scenario)
        self._described: dict[str, FmuDescription] = {}
        self._builtin: dict[str, str] = {}
        self._base_passed: bool | None = None
        self._base: Scenario | None = None

    def _descriptions(self, scenario: Scenario) -> dict[str, FmuDescription]:
        """Each FMU's description, read once per file (a built-in FMU's file found once per name)."""
        # slow: fishfmu.cosim.build loads Exudyn (the plant), which a sweep's client does not run
        from fishfmu.cosim.build import as_the_user_names_it, fmu_path
        fmus = {}
        for f in scenario.fmu:
            if f.builtin is not None:
                if f.builtin not in self._builtin:
                    self._builtin[f.builtin] = str(fmu_path(f))
                path = self._builtin[f.builtin]
            else:
                path = str(fmu_path(f))
            if path not in self._described:
                try:
                    self._described[path] = describe_file(path)
                except InputError as exc:
                    raise as_the_user_names_it(f, exc) from None
            fmus[f.name] = self._described[path]
        return fmus

    def _base_passes(self) -> bool:
        if self._base_passed is None:
            try:
                self._base = self.loader.load(self.spec.fixed)
                preflight(self._base, self.spec.scenario, self._descriptions(self._base))
                self._base_passed = True
            except InputError:
                self._base_passed = False
        return self._base_passed

    def prepare(self, params: dict[str, Any]) -> Scenario:
        """The point's scenario, validated as far as possible without running (raises InputError).

        It shares with the base scenario every top-level table the point's overrides leave alone (a sweep holds
        a scenario per point until its runs are sent: a few kB each rather than tens)."""
        overrides = point_overrides(self.spec, params, self.loader.data)
        sc = self.loader.load(overrides)
        fmus = self._descriptions(sc)
        keys = [k for k in overrides if k not in self.spec.fixed]
        changed = preflight_changes(keys)
        if changed is None or not self._base_passes():
            preflight(sc, self.spec.scenario, fmus)
        else:
            check_start_values(sc, self.spec.scenario, fmus, changed)
        tables = {dotted_parts(k)[0] for k in keys}
        self._base_passes()  # loads the base
        if self._base is None or "system" in tables:  # [system] ssp adds to [[fmu]] and [wiring]
            return sc
        return self._base.model_copy(update={t: getattr(sc, t) for t in tables})


def point_overrides(spec: SweepSpec, params: dict[str, Any], data: dict[str, Any] | None = None) -> dict[str, Any]:
    """The scenario overrides of a point: ``--set`` values, swept keys, and each swept scale factor times the
    scenario's value of the keys it scales (``data``: the scenario's TOML, when already read)."""
    out = dict(spec.fixed)
    if spec.scales and data is None:
        data = read_toml(Path(spec.scenario))
    for key, value in params.items():
        if key in spec.scales:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise InputError(f"--param {key}: a scale factor must be a number (got {value!r})")
            for scaled in spec.scales[key]:
                out[scaled] = float(get_dotted(data, scaled, spec.fixed)) * float(value)
        else:
            out[key] = value
    return out
