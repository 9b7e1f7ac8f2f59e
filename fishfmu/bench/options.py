"""The benchmarks' options, checked before anything is measured or written: bad input is exit 2 naming the option.

A benchmark runs the line as a scenario would, so its options have the bounds of the scenario keys they become
(``--comm-step``: ``run.comm_step_s``, ``--threads``: ``plant.numerics.threads``, ``--fish``: ``fish.count``,
``--first-seed``: ``run.seed``, ``--factor``: what ``serve --realtime`` takes); a measured time is at most
:data:`MAX_MEASURED_S`, a worker count at most :data:`MAX_WORKERS`.  And where its results go: a benchmark's JSON
or plot is never written over an input, into an input folder or into a measured dataset's folder
(:func:`check_result_file`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path

from plant.errors import InputError
from plant.fish.population import PopulationSpec
from plant.sim.params import NumericsParams

from fishfmu.output.ownership import check_single_file_target
from fishfmu.scenario.schema import RunSettings
from fishfmu.serve.options import REALTIME_RANGE

MAX_MEASURED_S = 3600.0
"""Simulated seconds one benchmark case measures (``bench pile --duration``, ``bench serve --continuous-s``)."""
MAX_WORKERS = 256
"""Worker processes of one measured setting (``bench sweep --workers``)."""


def _bounds(model: type, name: str) -> tuple[float, float]:
    lo = hi = None
    for constraint in model.model_fields[name].metadata:
        lo = getattr(constraint, "ge", getattr(constraint, "gt", lo))
        hi = getattr(constraint, "le", hi)
    return lo, hi


def number_in(value: float, option: str, lo: float, hi: float, lo_open: bool = False) -> float:
    """``value`` a finite number in [lo, hi] (``lo_open``: greater than ``lo``), else exit 2 naming ``option``."""
    low_ok = value > lo if lo_open else value >= lo
    if not (math.isfinite(value) and low_ok and value <= hi):
        low = f"greater than {lo:g}" if lo_open else f"at least {lo:g}"
        raise InputError(f"{value:g} is not a number {low} and at most {hi:g}", where=option)
    return value


def whole_in(value: int, option: str, lo: int, hi: int) -> int:
    if not lo <= value <= hi:
        raise InputError(f"{value} is not a whole number from {lo} to {hi}", where=option)
    return value


def pile(fish_counts: list[int], duration_s: float, comm_step_s: float, threads: int) -> None:
    lo, hi = _bounds(PopulationSpec, "count")
    for n in fish_counts:
        whole_in(n, "--fish", 0, hi)  # 0: the line alone
    number_in(duration_s, "--duration", 0.0, MAX_MEASURED_S, lo_open=True)
    number_in(comm_step_s, "--comm-step", *_bounds(RunSettings, "comm_step_s"))
    whole_in(threads, "--threads", *_bounds(NumericsParams, "threads"))


def serve(factor: float, continuous_s: float | None) -> None:
    number_in(factor, "--factor", *REALTIME_RANGE)
    if continuous_s is not None:
        number_in(continuous_s, "--continuous-s", 0.0, MAX_MEASURED_S, lo_open=True)


def diagnose(seeds: int, first_seed: int, strength: float) -> None:
    lo, hi = _bounds(RunSettings, "seed")
    whole_in(first_seed, "--first-seed", lo, hi - seeds + 1)  # every seed it uses is a scenario's seed
    number_in(strength, "--strength", 0.0, 10.0, lo_open=True)


def sweep(workers: Iterable[int]) -> None:
    for w in workers:
        whole_in(w, "--workers", 1, MAX_WORKERS)


def check_result_file(path: Path | None, inputs: Iterable[Path | None] = ()) -> None:
    """A benchmark's result file: never an input or inside an input folder, never in a measured dataset's folder
    (one holding ``dataset.toml``: what is there is read as the dataset), and replaced only if fishfmu wrote it
    (:func:`fishfmu.output.ownership.check_single_file_target`)."""
    if path is None:
        return
    folder = Path(path).parent
    if (folder / "dataset.toml").is_file():
        raise InputError(f"lies in the measured dataset folder {folder} (it holds dataset.toml); write the "
                         "benchmark's results outside it", file=path)
    check_single_file_target(path, inputs)
