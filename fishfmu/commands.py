"""One function per ``fishfmu`` command, callable from a script as from the command line.

Each does what its command does (checks the input, runs, writes) and returns what it produced; it prints
nothing.  :mod:`fishfmu.cli` parses arguments, calls one of these and prints the outcome.  Every command that
writes a folder goes through one lifecycle, :class:`fishfmu.output.run_folder.RunFolder`: the folder is made
under the ownership rules only once the input has been checked, ``run_info.json`` says ``running`` until one
finish writes it last, a signal stops the command with what there is written (``partial``).  Bad input raises
InputError before anything is written; a failure inside a run is reported in the returned outcome (``status``)
or raised as SimulationError where the command has nothing to return.

>>> from fishfmu import commands                                                     # doctest: +SKIP
>>> outcome = commands.run("scenarios/paper_test.toml", out="out/pt", overwrite=True) # doctest: +SKIP
>>> outcome.result.kpis["singulation_rate"], outcome.out_dir                          # doctest: +SKIP
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from plant.contract.measured import read_dataset
from plant.errors import InputError
from plant.sim.params import PlantParams
from plant.validation import read_toml, validate

from fishfmu import serve as serving
from fishfmu.cosim.build import check_scenario, checked
from fishfmu.cosim.results import RunResult
from fishfmu.cosim.runner import run_scenario
from fishfmu.fmu.build import BUILTIN_FMUS, build_fmu
from fishfmu.fmu.compile import FmuBuildError
from fishfmu.output.atomic import json_safe, write_bytes_atomic, write_text_atomic
from fishfmu.output.junit import junit_args_of_run, write_junit
from fishfmu.output.ownership import check_single_file_target
from fishfmu.output.run_folder import RunFolder
from fishfmu.scenario import schema  # schema.load_scenario at each call: a test replaces it to play a bug


def default_out(scenario_file: str | Path) -> Path:
    """Where a run goes without ``--out``: ``out/<scenario file name without .toml>``."""
    return Path("out") / Path(scenario_file).stem


def run_inputs(scenario_file: Path, sc: schema.Scenario, junit: Path | None) -> list:
    """The files a run reads (never written over); checks ``junit`` against them and for ownership."""
    inputs = [scenario_file, *(f.path for f in sc.fmu if f.path), *(f.parameter_file for f in sc.fmu if f.parameter_file),
              *(p.stl for p in sc.line.parts),
              *([sc.system.ssp] if sc.system.ssp else [])]
    if junit is not None:
        check_single_file_target(junit, inputs)
    return inputs


def refuse_served(sc: schema.Scenario, scenario_file: Path) -> None:
    """A scenario whose ``[opcua] inputs`` a PLC writes is served, not run: a run would hold them at their start
    values (no belt moves) and fail its bounds as if the line had."""
    if sc.opcua.inputs:
        raise InputError(f"{', '.join(sc.opcua.inputs)} are written by an OPC UA client (a PLC): serve this "
                         f"scenario with `fishfmu serve {scenario_file}`, or remove [opcua] inputs and feed them "
                         "in [wiring] to run it", file=scenario_file, where="opcua.inputs")


# ---------------------------------------------------------------- build-fmus

def build_fmus(names: Sequence[str], out: str | Path, defaults: dict[str, Any] | None = None) -> list[Path]:
    """Build built-in FMUs (all when ``names`` is empty) as .fmu files in ``out``; ``defaults`` bakes in
    parameter defaults (one FMU only).  Raises FmuBuildError naming the FMU that failed."""
    names = list(names) or list(BUILTIN_FMUS)
    if defaults and len(names) != 1:
        raise InputError("--param needs exactly one FMU name (parameters differ between FMUs)")
    out = Path(out)
    for name in names:  # an existing .fmu is replaced only if fishfmu wrote it
        check_single_file_target(out / f"{name}.fmu")
    built = []
    with tempfile.TemporaryDirectory(prefix="fishfmu-build-fmus-") as tmp:  # nothing of the build in ``out``
        for name in names:
            try:
                made = build_fmu(name, Path(tmp), defaults or {})
            except FmuBuildError as exc:
                raise FmuBuildError(f"{name}: {exc}") from exc
            write_bytes_atomic(out / made.name, made.read_bytes())
            built.append(out / made.name)
    return built


def export_fmu(scenario_file: str | Path, dest: str | Path, overrides: dict[str, Any] | None = None) -> Path:
    """The plant of a scenario as an FMI 2.0 co-simulation FMU at ``dest`` (see :mod:`fishfmu.cosim.plant_fmu`);
    an existing file is replaced only if fishfmu wrote it."""
    dest = Path(dest)
    if dest.suffix != ".fmu":
        raise InputError(f"'{dest}': an FMU file ends in .fmu", where="--out")
    sc = schema.load_scenario(scenario_file, overrides or {})
    check_single_file_target(dest, [scenario_file])
    # loaded by the commands that use it only: `fishfmu run` starts ~0.3 s sooner without the analysis and Dask
    from fishfmu.cosim.plant_fmu import export_plant_fmu
    with tempfile.TemporaryDirectory(prefix="fishfmu-export-") as tmp:
        built = export_plant_fmu(sc, Path(tmp))
        write_bytes_atomic(dest, built.read_bytes())
    return dest


def export_ssp(scenario_file: str | Path, dest: str | Path,
               overrides: dict[str, Any] | None = None) -> tuple[Path, list[str]]:
    """The scenario's system as an SSP 1.0 archive at ``dest`` (see :mod:`fishfmu.cosim.ssp_export`), and what SSP
    cannot say of it (also in the archive); an existing file is replaced only if fishfmu wrote it."""
    dest = Path(dest)
    if dest.suffix != ".ssp":
        raise InputError(f"'{dest}': an SSP archive ends in .ssp", where="--out")
    sc = schema.load_scenario(scenario_file, overrides or {})
    check_single_file_target(dest, run_inputs(Path(scenario_file), sc, None))
    check_scenario(sc, scenario_file)  # the wiring and every value checked against the FMUs, as a run checks them
    from fishfmu.cosim.ssp_export import write_ssp  # builds the plant FMU: pythonfmu, loaded when asked for
    data, notes = write_ssp(sc)
    write_bytes_atomic(dest, data)
    return dest, notes


# ---------------------------------------------------------------- run and serve

@dataclass
class RunOutcome:
    """A single run written into its folder (``fishfmu run``, ``fishfmu serve``)."""

    result: RunResult
    out_dir: Path
    replay: Path | None
    """The replay page, when asked for."""
    stop_exit_code: int | None
    """130/143 when a signal came: it stopped the run (``result.status == "partial"``), or came after the run's last
    step, while its results were written (whole)."""


def run(scenario_file: str | Path, out: str | Path | None = None, overrides: dict[str, Any] | None = None, *,
        junit: str | Path | None = None, overwrite: bool = False, report: bool = True, replay: bool = False,
        on_progress: Callable[[float, float], None] | None = None, clock: Any = None) -> RunOutcome:
    """Run a scenario into ``out`` (default ``out/<name>``): KPIs, signals, the run, report, JUnit.
    SIGINT/SIGTERM stop it after the current step with what there is written (``status = "partial"``).
    ``clock``: a :class:`fishfmu.cosim.master.StageClock` to time the master's stages (benchmarks)."""
    scenario_file = Path(scenario_file)
    junit = Path(junit) if junit is not None else None
    sc = schema.load_scenario(scenario_file, overrides or {})
    refuse_served(sc, scenario_file)
    # every FMU opened and checked once: bad input is found before anything is written
    with checked(sc, scenario_file) as checked_scenario:
        with RunFolder.open(out if out is not None else default_out(scenario_file), overwrite,
                            run_inputs(scenario_file, sc, junit), "run", scenario=str(scenario_file)) as folder:
            # Ctrl-C / SIGTERM: stop after this step, write what there is; one that comes after the last step, while
            # the results are written, lets them be written whole (the exit still says the signal came)
            with folder.stopping() as stop:
                result = run_scenario(sc, scenario_file, on_progress, record_poses=replay, stop=stop,
                                      checked_scenario=checked_scenario, **({"clock": clock} if clock else {}))
                folder.finish_run(result, report=report)
                replay_path = None
                if replay:
                    # loaded by the commands that use it only: `fishfmu run` starts ~0.3 s sooner without it
                    from fishfmu.output.replay import write_replay
                    replay_path = write_replay(folder.path)
                if junit is not None:
                    write_junit(junit, **junit_args_of_run(result, str(scenario_file)))
    return RunOutcome(result, folder.path, replay_path, stop.exit_code if stop.requested else None)


def serve(scenario_file: str | Path, out: str | Path | None = None, overrides: dict[str, Any] | None = None, *,
          endpoint: str = serving.DEFAULT_ENDPOINT, realtime: float | None = None, allow_remote: bool = False,
          user: str | None = None, certificates: serving.Certificates | None = None, overwrite: bool = False,
          report: bool = True, on_ready: Callable[[Any], None] | None = None, wait_for_start: bool = False,
          grace_s: float | None = None, users_file: str | Path | None = None,
          allow_anonymous_write: bool = False, pki: str | Path | None = None,
          modbus: str | None = None, live: str | None = None) -> RunOutcome:
    """Serve a scenario's line over OPC UA (:mod:`fishfmu.serve`) until its run ends (real time), a client calls
    stop() or a signal comes, then write the run into ``out`` (default ``out/<name>``) as :func:`run` does.
    ``wait_for_start``: the line waits for a client's start(); ``grace_s``: how long the server stays up after the
    run finished or failed (default :data:`fishfmu.serve.status.DEFAULT_GRACE_S`); ``users_file``: the users and
    their roles (:mod:`fishfmu.serve.access`); anonymous clients read only, unless ``allow_anonymous_write``;
    ``pki``: a folder for the server's certificate, made on first use, and the trusted clients'
    (:mod:`fishfmu.serve.pki`), instead of ``certificates``; ``modbus``: ``HOST:PORT`` of a Modbus TCP server
    beside OPC UA (:mod:`fishfmu.serve.modbus`); ``live``: ``HOST:PORT`` of the live 3D view
    (:mod:`fishfmu.serve.live`).

    Bad options (the endpoint, a port in use, the real-time factor, certificates, the user's password) are
    refused before the output folder is made; anything that fails after leaves ``run_info.json`` at ``failed``
    with what happened, never at ``running``.  ``on_ready(line)`` is called once clients can connect."""
    # slow (asyncua, about 0.4 s) and needed only here: the other commands start without it
    from fishfmu.serve.line import LineServer
    scenario_file = Path(scenario_file)
    if pki is not None:
        from fishfmu.serve.pki import pki_certificates  # with asyncua, as LineServer
        from fishfmu.serve.server import APPLICATION_URI  # asyncua: imported only to serve
        certificates = pki_certificates(Path(pki), APPLICATION_URI)
    problem = serving.options_problem(endpoint, allow_remote, realtime, certificates)
    if problem:
        raise problem
    sc = schema.load_scenario(scenario_file, overrides or {})
    with checked(sc, scenario_file) as c:
        grace = {} if grace_s is None else {"grace_s": grace_s}
        line = LineServer(c, endpoint, allow_remote, realtime, user, certificates, wait_for_start,
                          users_file=Path(users_file) if users_file is not None else None,
                          allow_anonymous_write=allow_anonymous_write, modbus=modbus, live=live, **grace)
        try:
            problem = serving.listen_problem(endpoint)
            if problem:
                raise InputError(problem, where="--endpoint")
            folder = RunFolder.open(out if out is not None else default_out(scenario_file), overwrite,
                                    run_inputs(scenario_file, sc, None), "serve", scenario=str(scenario_file))
        except BaseException:
            line.close()
            raise
        # a signal from here on only sets a flag: the server ends at its next look and the run is written
        with folder, folder.stopping() as stop:
            try:
                result = line.run(on_ready, stop)
            except InputError as exc:  # the port taken since it was checked: this served run failed, and says why
                folder.fail(exc)
                raise
            finally:
                line.close()
            folder.finish_run(result, report=report)
    return RunOutcome(result, folder.path, None, stop.exit_code if stop.requested else None)


def signal_list(scenario_file: str | Path, dest: str | Path | None = None,
                overrides: dict[str, Any] | None = None) -> str:
    """The signal list of the line ``fishfmu serve`` would serve for a scenario (:mod:`fishfmu.serve.signal_list`:
    every variable and method with its node id, type, unit, range, direction and description), as CSV text;
    written to ``dest`` too when given (an existing file is replaced only if fishfmu wrote it)."""
    # loaded by the command that uses it only, as serve's (the other commands start without them)
    from fishfmu.scenario.wiring import signal_names
    from fishfmu.serve.model import STATUS_ITEMS, information_model, served_signals
    from fishfmu.serve.signal_list import signal_list_csv
    sc = schema.load_scenario(scenario_file, overrides or {})
    if dest is not None:
        check_single_file_target(dest, [scenario_file])
    with checked(sc, scenario_file) as c:
        text = signal_list_csv(information_model(c, served_signals(c, signal_names(c.wiring)), STATUS_ITEMS))
    if dest is not None:
        write_text_atomic(Path(dest), text)
    return text


def check(scenario_file: str | Path, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Everything a run checks before it starts (the scenario, every FMU's archive, parameters and start values,
    the wiring, units, [record] and [expect]), without running: the stepping order, delayed links, conversions,
    setpoints and recorded variables.  Raises InputError naming what is wrong; writes nothing."""
    sc = schema.load_scenario(scenario_file, overrides)
    with checked(sc, scenario_file) as c:
        return {"scenario": str(scenario_file), "fmus": {n: {"path": str(o.path), "fmi": o.model_description.fmiVersion}
                                                         for n, o in c.opened.items()}, **c.wiring.describe(),
                "ssp_not_imported": list(sc.ssp_not_imported)}


def run_seeds(scenario_file: str | Path, n_seeds: int, out: str | Path | None = None,
              overrides: dict[str, Any] | None = None, *, junit: str | Path | None = None, overwrite: bool = False,
              scheduler: str | None = None, workers: int | None = None, progress: bool = False):
    """Run a scenario for ``n_seeds`` seeds on Dask into ``out``: KPIs as mean and 95 % CI, ``[expect]``
    on the means (:class:`fishfmu.batch.seeds.SeedsResult`)."""
    # loaded by the commands that use it only: `fishfmu run` starts ~0.3 s sooner without the analysis and Dask
    from fishfmu.batch.seeds import run_over_seeds, write_junit_means
    from fishfmu.batch.sweep_spec import check_size, make_spec
    scenario_file = Path(scenario_file)
    junit = Path(junit) if junit is not None else None
    overrides = overrides or {}
    check_size(1, n_seeds)  # before anything is written
    sc = schema.load_scenario(scenario_file, overrides)
    refuse_served(sc, scenario_file)
    check_scenario(sc, scenario_file)  # every FMU opened and checked: bad input before the folder
    spec = make_spec(scenario_file, {}, n_seeds, overrides)
    with RunFolder.open(out if out is not None else default_out(scenario_file), overwrite,
                        run_inputs(scenario_file, sc, junit), "run", scenario=str(scenario_file),
                        seeds=spec.seeds) as folder:
        result = run_over_seeds(scenario_file, sc, spec, folder, scheduler=scheduler, workers=workers,
                                progress=progress)
    if junit is not None:
        write_junit_means(result, junit, str(scenario_file))
    return result, folder.path


# ---------------------------------------------------------------- sweep

def sweep(scenario_file: str | Path, params: dict[str, list[Any]], seeds: int, out: str | Path,
          fixed: dict[str, Any] | None = None, scales: dict[str, list[str]] | None = None, **options: Any):
    """Sweep parameters x seeds on Dask into ``out`` (resumable; the sweep opens its folder as a
    :class:`~fishfmu.output.run_folder.RunFolder` of its own); ``scales``: named factors on several keys
    (:class:`fishfmu.batch.sweep_spec.SweepSpec`); ``options`` as :func:`fishfmu.batch.sweep.run_sweep` takes them
    (scheduler, workers, max_runs, retry_failed, ...)."""
    # loaded by the commands that use it only: `fishfmu run` starts ~0.3 s sooner without the analysis and Dask
    from fishfmu.batch.sweep import run_sweep
    from fishfmu.batch.sweep_spec import make_spec
    refuse_served(schema.load_scenario(scenario_file, fixed or {}), Path(scenario_file))
    spec = make_spec(Path(scenario_file), params, seeds, fixed or {}, scales)
    return spec, run_sweep(spec, Path(out), **options)


# ---------------------------------------------------------------- replay

def replay(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """Write a run (of ``fishfmu run --replay``) as one HTML page that replays it in 3D."""
    # loaded by the commands that use it only: `fishfmu run` starts ~0.3 s sooner without the analysis and Dask
    from fishfmu.output.replay import write_replay
    run_dir = Path(run_dir)
    check_single_file_target(Path(out) if out is not None else run_dir / "replay.html",
                             [run_dir / "run", run_dir / "poses.npz", run_dir / "scenario.resolved.toml"])
    return write_replay(run_dir, Path(out) if out is not None else None)


# ---------------------------------------------------------------- compare, diagnose, calibrate

def _dataset_and_params(dataset: Path, scenario_file: Path | None):
    """The dataset, and the plant (and drive) parameters of ``scenario_file``: a whole scenario, or a fragment
    of ``[plant]`` tables only (``calibrated.toml`` of ``fishfmu calibrate``); either laid over the plant measured
    data are replayed with (the paper's fish unless it names another)."""
    from fishfmu.analysis.resim import MEASURED_DATA_FISH, measured_data_plant  # here: `run` never loads the analysis
    ds = read_dataset(dataset)
    if scenario_file is None:
        return ds, measured_data_plant(), None
    data = read_toml(scenario_file)
    if set(data) <= {"plant"}:  # laid over the plant measured data are replayed with
        plant = data.get("plant", {})
        plant = {"fish_model": MEASURED_DATA_FISH, **plant} if isinstance(plant, dict) else plant
        return ds, validate(PlantParams, plant, file=scenario_file, prefix="plant."), None
    plant = data.get("plant")
    named = isinstance(plant, dict) and "fish_model" in plant
    sc = schema.load_scenario(scenario_file, None if named else {"plant.fish_model": MEASURED_DATA_FISH})
    drives = [f.parameters for f in sc.fmu if f.builtin == "conveyor_drive"]
    return ds, sc.plant, (drives[0] if drives else None)


@dataclass
class CompareOutcome:
    dataset_name: str
    n_runs: int
    comparison: Any
    """:class:`fishfmu.analysis.compare.Comparison`"""
    paths: dict[str, Path]
    out_dir: Path
    stopped_by: str | None
    stop_exit_code: int | None
    failure: str | None
    """A re-simulation that failed (the others are compared and written)."""


def compare(dataset: str | Path, out: str | Path, scenario_file: str | Path | None = None,
            workers: int | None = None, overwrite: bool = False) -> CompareOutcome:
    """Re-simulate every measured run of ``dataset`` and write what the simulation gets wrong into ``out``."""
    # loaded by the commands that use it only: `fishfmu run` starts ~0.3 s sooner without the analysis and Dask
    from fishfmu.analysis.compare import compare_dataset, write_comparison
    dataset = Path(dataset)
    scenario_file = Path(scenario_file) if scenario_file is not None else None
    ds, params, drive = _dataset_and_params(dataset, scenario_file)
    with RunFolder.open(out, overwrite, [dataset, scenario_file], "compare", dataset=str(dataset)) as folder:
        c = compare_dataset(ds, params, workers, drive)  # a signal: the runs re-simulated by then are compared
        paths = write_comparison(c, folder.path)
        stopped = folder.stopped
        failure = None if stopped else c.failure()
        folder.finish("partial" if stopped else "failed" if failure else "ok",
                      **({"stopped_by": stopped.signal_name} if stopped else {}), **({"error": failure} if failure else {}))
    return CompareOutcome(ds.name, len(ds.runs), c, paths, folder.path, stopped.signal_name if stopped else None,
                          stopped.exit_code if stopped else None, failure)


@dataclass
class DiagnoseOutcome:
    diagnosis: Any
    """:class:`fishfmu.analysis.diagnose.Diagnosis`"""
    paths: dict[str, Path]
    out_dir: Path


def _analysis_into(command: str, dataset: Path, out: str | Path, scenario_file: Path | None, overwrite: bool,
                   analyse: Callable[[Any, Any], Any], write: Callable[[Any, Any, Path], dict[str, Path]]):
    """An analysis of ``dataset`` written into the folder ``out``: (result, base plant parameters, paths,
    folder).  A run the model cannot re-simulate is exit 3, with run_info.json saying why."""
    # loaded by the commands that use it only (Exudyn behind it): `fishfmu run` starts sooner without it
    from fishfmu.analysis.resim import refuse_unreplayed
    ds, params, _ = _dataset_and_params(dataset, scenario_file)
    refuse_unreplayed(ds, command)  # before the output folder exists: bad input writes nothing
    with RunFolder.open(out, overwrite, [dataset, scenario_file], command, dataset=str(dataset)) as folder:
        result = analyse(ds, params)
        paths = write(result, params, folder.path)
        folder.finish("ok")
    return result, params, paths, folder.path


def diagnose(dataset: str | Path, out: str | Path, scenario_file: str | Path | None = None,
             workers: int | None = None, overwrite: bool = False,
             progress: Callable[[str], None] | None = None, calibrate: bool = True,
             without: tuple[str, ...] = ()) -> DiagnoseOutcome:
    """Name the causes of what the simulation gets wrong on ``dataset`` (or say that it fits, or where an unexplained
    discrepancy is), fit them, measure the held-out gain. ``without``: candidate causes left out."""
    # loaded by the commands that use it only: `fishfmu run` starts ~0.3 s sooner without the analysis and Dask
    from fishfmu.analysis.diagnose import diagnose as diagnose_dataset
    # slow (matplotlib, about 0.5 s) and needed only here: the other commands start without it
    from fishfmu.analysis.diagnose_report import write_diagnosis
    from fishfmu.analysis.candidates import CANDIDATES
    unknown = [w for w in without if w not in CANDIDATES]
    if unknown:  # before the output folder exists: bad input writes nothing
        raise InputError(f"--without {unknown[0]}: no such candidate cause (known: {', '.join(CANDIDATES)})")
    d, _, paths, out_dir = _analysis_into(
        "diagnose", Path(dataset), out, Path(scenario_file) if scenario_file is not None else None, overwrite,
        lambda ds, params: diagnose_dataset(ds, params, workers, progress=progress, calibrate=calibrate,
                                            without=without),
        lambda d, params, folder: write_diagnosis(d, folder))
    return DiagnoseOutcome(d, paths, out_dir)


@dataclass
class CalibrateOutcome:
    calibration: Any
    """:class:`fishfmu.analysis.calibrate.Calibration`"""
    base: Any
    """The plant parameters it started from."""
    paths: dict[str, Path]
    out_dir: Path


def calibrate(dataset: str | Path, out: str | Path, scenario_file: str | Path | None = None,
              workers: int | None = None, overwrite: bool = False,
              progress: Callable[[str], None] | None = None) -> CalibrateOutcome:
    """Fit the line's base parameters on ``dataset``; ``out`` gets ``calibrated.toml`` and ``calibration.json``."""
    # loaded by the commands that use it only: `fishfmu run` starts ~0.3 s sooner without the analysis and Dask
    from fishfmu.analysis.calibrate import calibrate as calibrate_dataset
    from fishfmu.analysis.calibrate_report import write_calibration
    c, params, paths, out_dir = _analysis_into(
        "calibrate", Path(dataset), out, Path(scenario_file) if scenario_file is not None else None, overwrite,
        lambda ds, params: calibrate_dataset(ds, params, workers, progress=progress), write_calibration)
    return CalibrateOutcome(c, params, paths, out_dir)


# ---------------------------------------------------------------- single files a command writes

def check_targets(*paths: Path | None) -> None:
    """Before measuring: each single-file output may be replaced only if fishfmu wrote it."""
    for p in paths:
        if p is not None:
            check_single_file_target(p)


def write_json(path: Path, doc: Any) -> Path:
    """A JSON document written atomically (under the folder's manifest)."""
    write_text_atomic(path, json.dumps(json_safe(doc), indent=2) + "\n")
    return path
