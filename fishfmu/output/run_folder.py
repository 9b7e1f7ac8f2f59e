"""Writing a run's folder: resolved scenario, KPIs, signals, the run as measured data, a report.

Files are written to a temporary name and renamed into place, so a crash or an interrupt never
leaves a half-written file under its final name.  ``run_info.json`` says whether the run
completed (``status``): it is written as ``running`` before the run starts (:func:`mark_running`)
and again, last, when the outputs are complete; a folder whose ``run_info.json`` still says
``running`` holds a run that was killed before it could write its results.  ``kpis.json`` carries
the same ``status`` (``ok``, ``failed``: stopped by an error, ``partial``: stopped on request), the
``error`` message (null when ok) and the simulated time reached, and nothing that depends on the machine or the wall clock, so that the
same scenario and seed give the same bytes (wall times are in ``run_info.json``).  An output folder that holds anything not written by
fishfmu is never touched; one from an earlier run is replaced only when asked (``overwrite``).
What is fishfmu's is decided by the folder's manifest alone (:mod:`fishfmu.output.ownership`); every
writer here records what it writes there before the file appears under its name.
"""

from __future__ import annotations

import platform
import shutil
from pathlib import Path
from typing import Any, Iterable, Sequence
from xml.etree import ElementTree as ET


from plant.contract.measured import write_dataset

from fishfmu.output import manifest, ownership
from fishfmu.output.atomic import MARKER, json_safe, write_json_atomic, write_run_info, write_text_atomic
from fishfmu.cosim.results import ExpectResult, RunResult
from fishfmu.scenario.schema import resolved_toml


def prepare_out_dir(out: str | Path, overwrite: bool, inputs: Iterable[str | Path | None] = (),
                    command: str | None = None) -> Path:
    """Create ``out``; refuse a folder with foreign files, an input in it, or an earlier run unless
    ``overwrite`` (see :func:`fishfmu.output.ownership.prepare_out_dir`)."""
    return ownership.prepare_out_dir(out, overwrite, inputs, command)


def mark_running(out: Path, scenario_file: str | Path | None = None) -> None:
    """Mark ``out`` as fishfmu's before the run starts (``run_info.json`` with status ``running``)."""
    write_run_info(out, "running", scenario=None if scenario_file is None else str(scenario_file))


def discard_if_unused(out: Path) -> None:
    """Remove ``out`` again if it holds nothing but the ``running`` marker (bad input found late)."""
    try:
        if [p.name for p in out.iterdir() if not manifest.is_internal(p.name)] == [MARKER]:
            manifest.forget(out)
            for p in out.iterdir():
                p.unlink()
            out.rmdir()
    except OSError:
        pass


def kpis_document(result: RunResult, partial: bool = False) -> dict[str, Any]:
    """kpis.json: the KPIs as plain numbers, the expect bounds with their outcome, the run's status
    and the simulated time it reached (nothing from the wall clock: the same run, the same bytes)."""
    doc = dict(result.kpis)
    doc["status"] = "partial" if partial else result.status
    doc["error"] = result.error
    doc["t_end_s"] = round(result.t_end_s, 6)
    doc["expect"] = {e.kpi: {"value": e.value, "min": e.min, "max": e.max, "ok": e.ok} for e in result.expect}
    return json_safe(doc)




def write_outputs(result: RunResult, out: Path, partial: bool = False, report: bool = True) -> dict[str, Path]:
    """Write every output of a run into ``out`` (already prepared); returns the paths written.

    A write that fails (disk full, read-only) raises an :class:`~fishfmu.output.manifest.OutputError`
    saying so; ``run_info.json`` is then set to ``failed`` with that message when it still can be."""
    try:
        return _write_outputs(result, out, partial, report)
    except (manifest.OutputError, OSError) as exc:
        err = exc if isinstance(exc, manifest.OutputError) else manifest.os_error(exc, exc.filename or out)
        try:
            write_run_info(out, "failed", error=f"writing the outputs failed: {err}", t_end_s=round(result.t_end_s, 6))
            note = f"{MARKER} says failed"
        except OSError:
            note = f"{MARKER} could not be updated and still says running"
        raise manifest.OutputError(f"{err.message}; the outputs are incomplete ({note})", file=err.file) from None


def _write_outputs(result: RunResult, out: Path, partial: bool, report: bool) -> dict[str, Path]:
    paths = {
        "scenario": out / "scenario.resolved.toml",
        "kpis": out / "kpis.json",
        "signals": out / "signals.csv",
        "run": out / "run",
        "report": out / "report.html",
        "info": out / MARKER,
    }
    write_text_atomic(paths["scenario"], resolved_toml(result.scenario))
    partial = partial or result.status == "partial"
    write_json_atomic(paths["kpis"], kpis_document(result, partial))
    write_text_atomic(paths["signals"], result.signals.to_csv(index=False, float_format="%.10g"))
    if paths["run"].exists():
        shutil.rmtree(paths["run"])
    manifest.write_tree_atomic(paths["run"], lambda tmp: write_dataset(result.dataset(), tmp))
    if result.poses is not None:
        paths["poses"] = out / "poses.npz"
        import numpy as np
        manifest.write_file_atomic(paths["poses"], lambda fh: np.savez_compressed(fh, **result.poses))
    if report:
        from fishfmu.output.report import write_report
        write_report(result, out)
    import fmpy

    from plant.sim.model import exu  # where exudyn is imported (a missing system library is reported there)
    write_run_info(
        out, "partial" if partial else result.status,
        error=result.error,
        t_end_s=round(result.t_end_s, 6),
        wall_s=round(result.wall_s, 3),
        real_time_factor=round(result.t_end_s / result.wall_s, 3) if result.wall_s > 0 else None,
        setup_s=round(result.timings_s.get("setup", 0.0), 3),
        seed=result.scenario.run.seed,
        drops_raised=[{"fish_id": d.fish_id, "raised_by_m": round(d.raised_by_m, 4)} for d in result.drop_adjustments],
        energy_watch={k: round(v, 4) for k, v in result.energy_watch.items()},
        wiring=result.wiring,
        **({"served": result.served} if result.served is not None else {}),
        versions={"exudyn": exu.config.Version(), "fmpy": fmpy.__version__, "python": platform.python_version()},
    )
    return paths


def write_junit(path: Path, suite_name: str, classname: str, expect: Sequence[ExpectResult], *,
                error: tuple[str, str | None] | None = None, on: str | None = None, time_s: float | None = None,
                properties: dict[str, str] | None = None) -> None:
    """Each [expect] bound as a JUnit test case (CI systems show them like unit tests): the one JUnit
    writer, for a single run (:func:`junit_args_of_run`) and for ``run --seeds``.

    ``error``: (message, details) of a run that failed, as a test case ``simulation`` with an
    ``error``; ``on``: what the bounds were checked on (``"mean"`` over seeds), put before every
    case's message, which then labels passed cases too; ``time_s`` and ``properties``: the suite's
    ``time`` attribute and ``<properties>``, left out when None."""
    attrs = {"name": suite_name, "tests": str(len(expect)), "failures": str(sum(not e.ok for e in expect)),
             "errors": "1" if error is not None else "0"}
    if time_s is not None:
        attrs["time"] = f"{time_s:.3f}"
    suite = ET.Element("testsuite", attrs)
    if properties is not None:
        props = ET.SubElement(suite, "properties")
        for k, v in properties.items():
            ET.SubElement(props, "property", name=k, value=v)
    if error is not None:
        case = ET.SubElement(suite, "testcase", classname=classname, name="simulation")
        ET.SubElement(case, "error", message=error[0]).text = error[1]
    for e in expect:
        case = ET.SubElement(suite, "testcase", classname=classname, name=f"expect.{e.kpi}")
        if on is not None:
            ET.SubElement(case, "failure" if not e.ok else "system-out", message=f"{on} {e.message}").text = e.message
        elif not e.ok:
            ET.SubElement(case, "failure", message=e.message).text = e.message
        else:
            ET.SubElement(case, "system-out").text = e.message
    ET.indent(suite)
    write_text_atomic(Path(path), ET.tostring(suite, encoding="unicode", xml_declaration=True) + "\n")


def junit_args_of_run(result: RunResult, scenario_file: str | None) -> dict[str, Any]:
    """:func:`write_junit`'s arguments for a single run: suite ``fishfmu:<run name>``, its wall time,
    scenario and seed as properties, an error case when the run did not finish ok."""
    name = result.scenario.run.name
    return {"suite_name": f"fishfmu:{name}", "classname": f"fishfmu.{name}", "expect": result.expect,
            "error": (result.error or "failed", result.error) if result.status != "ok" else None,
            "time_s": result.wall_s,
            "properties": {"scenario": str(scenario_file or name), "seed": str(result.scenario.run.seed)}}
