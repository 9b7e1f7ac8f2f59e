"""A command's output folder from start to finish: the one writer of ``run_info.json`` and ``kpis.json``.

Every command that writes a folder (``run``, ``run --seeds``, ``serve``, ``sweep``, ``compare``, ``diagnose``,
``calibrate``) goes through a :class:`RunFolder`:

1. :meth:`RunFolder.open` makes the folder under the ownership rules (:mod:`fishfmu.output.ownership`: a folder
   with anything fishfmu did not write is never touched, an earlier result is replaced only when asked), writes
   ``run_info.json`` as ``running`` and registers the folder with the command's session
   (:mod:`fishfmu.session`), which tells it when a signal ends the command;
2. the command runs: a loop that steps a run polls the stop request of :meth:`RunFolder.stopping` (a signal asks
   it to stop after its current step), a loop over worker results gets :class:`fishfmu.session.Interrupted`;
3. one finish writes ``run_info.json`` last: :meth:`RunFolder.finish_run` (a single run: every output of it,
   ``kpis.json`` with the run's status), :meth:`RunFolder.finish` (anything else: the status and fields given).
   Leaving the ``with`` block by an exception finishes the folder too: a signal (``partial``, with
   ``stopped_by``), bad input found late (the folder is removed again when nothing but the marker is in it),
   anything else (``failed``, with the error).  So ``run_info.json`` says ``running`` only while the command
   runs, or when it was killed outright (``kill -9``, power loss) before it could write its results.

``run_info.json``'s ``status``: ``running``, ``ok``, ``failed`` (``error`` says why), ``partial`` (stopped by a
signal, or a sweep not run to its end); it carries the folder's ``command`` and what it ran (``scenario``,
``dataset``, ``seeds``) besides each finish's fields.  ``kpis.json`` carries the same ``status``, the ``error``
message (null when ok) and the simulated time reached, and nothing that depends on the machine or the wall clock,
so that the same scenario and seed give the same bytes (wall times are in ``run_info.json``).  Every file is
written to a temporary name and renamed into place, recorded in the folder's manifest first.

>>> with RunFolder.open("out/pt", overwrite=True, command="run", scenario="pt.toml") as folder:  # doctest: +SKIP
...     with folder.stopping() as stop:
...         folder.finish_run(run_scenario(sc, stop=stop))
"""

from __future__ import annotations

import contextlib
import json
import platform
import shutil
import signal
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import fmpy
import numpy as np
import pandas as pd

from plant.errors import InputError, SimulationError
from plant.contract.measured import write_dataset

from fishfmu import session
from fishfmu.cosim.results import RunResult
from fishfmu.cosim.stop import StopRequest
from fishfmu.output import lock, manifest, ownership
from fishfmu.output.atomic import json_safe, write_json_atomic, write_text_atomic
from fishfmu.output.manifest_state import OutputError, is_internal, os_error
from fishfmu.scenario.schema import resolved_toml

MARKER = "run_info.json"
"""Says what the folder holds and whether the command that wrote it finished (``status``)."""
KPIS = "kpis.json"


def write_run_info(out: Path, /, status: str, **fields: Any) -> None:
    """Write ``out/run_info.json``: ``status`` and ``fields`` (made JSON-safe, see :func:`json_safe`).  The one
    writer of that file: :class:`RunFolder` and :func:`mark_partial` call it."""
    write_json_atomic(Path(out) / MARKER, json_safe({"status": status, **fields}))


def mark_partial(out_dir: Path | None, signum: int, info: dict[str, Any] | None = None) -> None:
    """Set ``status`` to ``partial`` in ``out_dir/run_info.json`` with ``stopped_by`` the signal, written with
    ``info`` if the folder holds none yet (nothing happens when the folder does not exist)."""
    if out_dir is None or not Path(out_dir).is_dir():
        return
    try:
        found = json.loads((Path(out_dir) / MARKER).read_text())
    except FileNotFoundError:
        found = dict(info or {})
    except (OSError, ValueError):
        return
    if not isinstance(found, dict) or found.get("status") == "partial":
        return
    found.update(status="partial", stopped_by=signal.Signals(signum).name)
    with contextlib.suppress(OSError):
        write_run_info(out_dir, **found)


def prepare_out_dir(out: str | Path, overwrite: bool, inputs: Iterable[str | Path | None] = (),
                    command: str | None = None) -> Path:
    """Create ``out`` for a new result without marking it (see :func:`fishfmu.output.ownership.prepare_out_dir`);
    a command opens a :class:`RunFolder` instead."""
    return ownership.prepare_out_dir(out, overwrite, inputs, command)


def error_text(exc: BaseException) -> str:
    """What ``run_info.json`` says of an error: our own errors' messages as they are, anything else (a bug) with
    its type."""
    return str(exc) if isinstance(exc, (InputError, SimulationError)) else f"{type(exc).__name__}: {exc}"


class RunFolder:
    """One command's output folder, from :meth:`open` to its finish (see the module docstring)."""

    def __init__(self, path: str | Path, info: dict[str, Any] | None = None) -> None:
        self.path = Path(path)
        self.info = dict(info or {})
        """What every ``run_info.json`` of this folder says besides its status (command, scenario, dataset)."""
        self.status: str | None = None
        """The status ``run_info.json`` says now (None before this object wrote one)."""
        self.stop: StopRequest | None = None
        """The request a stepping loop polls, inside :meth:`stopping`."""

    # ---- start ------------------------------------------------------------------------------------------
    @classmethod
    def open(cls, out: str | Path, overwrite: bool, inputs: Iterable[str | Path | None] = (),
             command: str | None = None, **info: Any) -> RunFolder:
        """Make the folder ``out`` for a new result (refusing foreign files, an input in it, an earlier result
        without ``overwrite``), mark it ``running`` and register it with the command's session."""
        path = ownership.prepare_out_dir(out, overwrite, inputs, command)
        return cls.start(path, **({"command": command} if command else {}), **info)

    @classmethod
    def start(cls, path: str | Path, **info: Any) -> RunFolder:
        """Mark a folder already made (a resumable sweep's) ``running`` and register it with the session."""
        folder = cls(path, info)
        folder.finish("running")
        session.register_output(folder.path, folder.mark_partial)
        return folder

    def __enter__(self) -> RunFolder:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: Any) -> None:
        """Leaving by an exception while the folder still says ``running``: a signal is ``partial``, bad input
        found late removes a folder that holds nothing else, anything else is ``failed``."""
        if exc is None or self.status != "running":
            return
        if isinstance(exc, session.Interrupted):
            self.mark_partial(exc.signum)
        elif isinstance(exc, KeyboardInterrupt):  # Ctrl-C without a session (fishfmu as a library)
            self.mark_partial(signal.SIGINT)
        elif isinstance(exc, InputError) and self.discard_if_unused():
            pass
        elif isinstance(exc, Exception):
            self.fail(exc)

    # ---- while it runs ------------------------------------------------------------------------------------
    @contextmanager
    def stopping(self) -> Iterator[StopRequest]:
        """For the block, SIGINT/SIGTERM ask the run to stop after its current step: the request yielded is what
        its loop polls (:func:`fishfmu.session.stop_between_steps`)."""
        with session.stop_between_steps() as stop:
            self.stop = stop
            yield stop

    @property
    def stopped(self) -> StopRequest | None:
        """The stop request a signal set, if one stopped the command (its ``signal_name`` and ``exit_code``): the
        stepping loop's, or the session's."""
        s = self.stop if self.stop is not None else session.current()
        return s if s is not None and s.requested else None

    # ---- finishes -------------------------------------------------------------------------------------------
    def finish(self, status: str, **fields: Any) -> None:
        """Write ``run_info.json``: ``status``, the folder's own fields, then ``fields``."""
        write_run_info(self.path, status, **{**self.info, **fields})
        self.status = status

    def fail(self, error: BaseException | str, **fields: Any) -> None:
        """``failed`` with the error (see :func:`error_text`), when the file can still be written."""
        with contextlib.suppress(OSError):
            self.finish("failed", error=error if isinstance(error, str) else error_text(error), **fields)

    def mark_partial(self, signum: int) -> None:
        """``partial``, stopped by ``signum``, unless the folder is finished already."""
        if self.status in (None, "running"):
            mark_partial(self.path, signum, {**self.info, "status": "running"})
            self.status = "partial"

    def discard_if_unused(self) -> bool:
        """Remove the folder again if it holds nothing but the ``running`` marker (bad input found late); True if
        it was removed."""
        try:
            if [p.name for p in self.path.iterdir() if not is_internal(p.name)] == [MARKER]:
                manifest.forget(self.path)
                for p in self.path.iterdir():
                    p.unlink()
                self.path.rmdir()
                lock.release(self.path)
                return True
        except OSError:
            pass
        return False

    def write_kpis(self, doc: dict[str, Any]) -> Path:
        """``kpis.json``: ``doc`` made JSON-safe."""
        write_json_atomic(self.path / KPIS, json_safe(doc))
        return self.path / KPIS

    def finish_run(self, result: RunResult, report: bool = True, partial: bool = False) -> dict[str, Path]:
        """Write every output of a single run (``partial``: whatever its status, it was cut short), then
        ``run_info.json``; returns the paths written.

        A write that fails (disk full, read-only) raises an :class:`~fishfmu.output.manifest_state.OutputError`
        saying so; ``run_info.json`` is then set to ``failed`` with that message when it still can be."""
        try:
            return self._write_run(result, report, partial or result.status == "partial")
        except (OutputError, OSError) as exc:
            err = exc if isinstance(exc, OutputError) else os_error(exc, exc.filename or self.path)
            try:
                self.finish("failed", error=f"writing the outputs failed: {err}", t_end_s=round(result.t_end_s, 6))
                note = f"{MARKER} says failed"
            except OSError:
                note = f"{MARKER} could not be updated and still says running"
            raise OutputError(f"{err.message}; the outputs are incomplete ({note})", file=err.file) from None

    def _write_run(self, result: RunResult, report: bool, partial: bool) -> dict[str, Path]:
        out = self.path
        paths = {"scenario": out / "scenario.resolved.toml", "kpis": out / KPIS, "signals": out / "signals.csv",
                 "run": out / "run", "report": out / "report.html", "info": out / MARKER}
        write_text_atomic(paths["scenario"], resolved_toml(result.scenario))
        self.write_kpis(kpis_document(result, partial))
        write_text_atomic(paths["signals"], signals_csv(result.signals))
        if paths["run"].exists():
            shutil.rmtree(paths["run"])
        manifest.write_tree_atomic(paths["run"], lambda tmp: write_dataset(result.dataset(), tmp))
        if result.poses is not None:
            paths["poses"] = out / "poses.npz"
            manifest.write_file_atomic(paths["poses"], lambda fh: np.savez_compressed(fh, **result.poses))
        if report:
            # slow (matplotlib, about 0.5 s) and optional (--no-report)
            from fishfmu.output.report import write_report
            write_report(result, out)
        from plant.sim.exudyn_module import exu  # where exudyn is imported (a missing system library is reported there)
        self.finish(
            "partial" if partial else result.status,
            error=result.error,
            t_end_s=round(result.t_end_s, 6),
            wall_s=round(result.wall_s, 3),
            real_time_factor=round(result.t_end_s / result.wall_s, 3) if result.wall_s > 0 else None,
            setup_s=round(result.timings_s.get("setup", 0.0), 3),
            seed=result.scenario.run.seed,
            drops_raised=[{"fish_id": d.fish_id, "raised_by_m": round(d.raised_by_m, 4)}
                          for d in result.drop_adjustments],
            energy_watch={k: round(v, 4) for k, v in result.energy_watch.items()},
            wiring=result.wiring,
            **({"served": result.served} if result.served is not None else {}),
            versions={"exudyn": exu.config.Version(), "fmpy": fmpy.__version__, "python": platform.python_version()},
        )
        return paths


def signals_csv(signals: pd.DataFrame) -> str:
    """signals.csv's text: every float to ten significant digits, a missing value empty.  The same text as pandas'
    ``to_csv(float_format="%.10g")``, which formats value by value in Python (about 0.1 s of a dumped batch's 4 s)."""
    text = {}
    for name, column in signals.items():
        if column.dtype.kind == "f":
            text[name] = np.array(["" if v != v else "%.10g" % v for v in column.to_numpy().tolist()], dtype=object)
        else:
            text[name] = column
    return pd.DataFrame(text, index=signals.index).to_csv(index=False)


def kpis_document(result: RunResult, partial: bool = False) -> dict[str, Any]:
    """kpis.json of a single run: the KPIs as plain numbers, the expect bounds with their outcome, the run's status
    and the simulated time it reached (nothing from the wall clock: the same run, the same bytes)."""
    doc = dict(result.kpis)
    doc["status"] = "partial" if partial else result.status
    doc["error"] = result.error
    doc["t_end_s"] = round(result.t_end_s, 6)
    doc["expect"] = {e.kpi: {"value": e.value, "min": e.min, "max": e.max, "ok": e.ok} for e in result.expect}
    return json_safe(doc)


def write_outputs(result: RunResult, out: Path, partial: bool = False, report: bool = True) -> dict[str, Path]:
    """Every output of a run into the folder ``out`` (already prepared: :func:`prepare_out_dir`), as
    :meth:`RunFolder.finish_run` writes them; for scripts and tests that run without a command."""
    return RunFolder(out).finish_run(result, report, partial)
