"""Re-simulating measured runs: the same line, fish, drops and belt speeds as measured.

A measured run (contracts/measured-data.md) says which fish were dropped where and when and how
fast each belt ran; :func:`resimulate` runs the plant with exactly that (belt surfaces follow the
logged ``speed_mps``, devices the logged commands of ``device_commands.csv``), so that what differs between the
simulated and the measured run is the fish physics.  A line with devices whose run did not log their commands
cannot be replayed as it ran: its devices stay home, and :func:`unreplayed_devices` says so for the analyses to
leave out (compare) or refuse (calibrate, diagnose) what depends on them.  The side a fish lands on is not measured: it is drawn from a seed made of the run
id, so every re-simulation of a run (with any model variant) uses the same draw.

:func:`drive_check` runs the conveyor-drive FMU alone on the logged setpoints and the belt loads
of the re-simulation, to compare the drive model with the logged belt speeds.

Runs are independent: :func:`resimulate_many` spreads them over worker processes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import multiprocessing
import os
import signal
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
import pandas as pd

from plant.errors import InputError, SimulationError
from plant.contract.line import Line
from plant.contract.measured import Dataset, Run
from plant.sim.params import PlantParams
from plant.contract.plausibility import MAX_RESIM_S
from plant.contract.measured import fish_from_frame
from plant.contract.device_commands import command_schedule
from plant.sim.simulate import SimulatedRun, simulate_plant

from fishfmu.analysis.observations import DROP_READ_S, drop_slip
from fishfmu.analysis.residuals import residuals_of
from fishfmu.fmu.archive import open_fmu
from fishfmu.fmu.build import builtin_fmu
from fishfmu.fmu.instance import InProcessFmu
from fishfmu.session import STOPS, deferred_signals, raise_if_signalled


MEASURED_DATA_FISH = "paper5"
"""The fish measured runs are re-simulated with when no scenario says otherwise (compare, calibrate, diagnose).
``diagnose``'s benchmark on the independent simulator's datasets was measured with the paper's five-body fish; on
the joined fish, the default of scenarios since issue 43, our own synthetic mucus dataset is no longer named (its
drop statistics change), and the benchmark has not been re-measured: so the analyses keep the fish they were
measured with, and what they hand over (``calibrated.toml``, ``fragment.toml``) names it."""


def measured_data_plant() -> PlantParams:
    """The plant measured runs are replayed with when no scenario is given: the paper's fish
    (:data:`MEASURED_DATA_FISH`); a scenario or a ``calibrated.toml`` is laid over it (``fishfmu.commands``)."""
    return PlantParams(fish_model=MEASURED_DATA_FISH)


def fish_model_lines(params: PlantParams) -> str:
    """A fragment's first table when its values were fitted on another fish than a scenario's default: without it,
    the values would be pasted onto a fish they were not fitted on."""
    if params.fish_model == PlantParams.model_fields["fish_model"].default:
        return ""
    return f'[plant]\nfish_model = "{params.fish_model}"  # the fish these values were fitted with\n'


@dataclass
class Resim:
    """One re-simulated run: the simulated tables (measured-data format) and the belt loads."""

    run_id: str
    sim: SimulatedRun
    loads: pd.DataFrame
    """t_s, conveyor_id, load_force_n, load_mass_kg at every communication step."""
    error: str | None = None
    residuals: object | None = None
    """The run's :class:`~fishfmu.analysis.fitting.RunResiduals` against this re-simulation, when the worker
    computed them (``resimulate_many(..., residuals=True)``: in parallel, not one after the other in the parent)."""


def run_seed(run_id: str, seed: int = 0) -> int:
    return int.from_bytes(hashlib.sha256(f"{run_id}:{seed}".encode()).digest()[:4], "little")


def belt_speed_function(belts: pd.DataFrame, conveyor_ids: list[str]):
    """Belt speeds at time t, linearly interpolated from the drive log (held before/after it)."""
    tables = {}
    for cid in conveyor_ids:
        b = belts[belts["conveyor_id"] == cid]
        tables[cid] = (b["t_s"].to_numpy(float), b["speed_mps"].to_numpy(float)) if len(b) else (np.array([0.0]),
                                                                                                 np.array([0.0]))

    def speeds(t: float) -> dict[str, float]:
        return {cid: float(np.interp(t, ts, vs)) for cid, (ts, vs) in tables.items()}

    return speeds


def unreplayed_devices(line: Line, run: Run) -> str | None:
    """Why the run's devices cannot be replayed (the line has devices, the run has no ``device_commands.csv``), in
    words; None when they can (or there are none)."""
    if not line.devices or run.device_commands is not None:
        return None
    names = ", ".join(f"'{d.id}'" for d in line.devices[:5]) + (" ..." if len(line.devices) > 5 else "")
    return (f"run '{run.id}': the line's device{'s' if len(line.devices) > 1 else ''} {names} cannot be replayed: "
            "the run has no device_commands.csv (rejections.csv says which fish left, not when the devices moved), "
            f"so the re-simulation keeps {'them' if len(line.devices) > 1 else 'it'} home")


def refuse_unreplayed(dataset: Dataset, command: str) -> None:
    """A fit (calibrate, diagnose) on runs whose devices it cannot fire would fit a line whose devices never move:
    refused, naming the first such run (docs/diagnosis.md)."""
    for run in dataset.runs:
        why = unreplayed_devices(dataset.line, run)
        if why:
            raise InputError(f"{command} refuses: {why}; add the run's device_commands.csv, or compare the dataset "
                             "(which leaves out what the devices change)", file=run.path)


def run_duration_s(run: Run) -> float:
    """Long enough for everything the run measured, plus a little."""
    ends = [float(run.fish["drop_t_s"].max())]
    if len(run.tracks):
        ends.append(float(run.tracks["t_s"].max()))
    if len(run.photoeyes):
        ends.append(float(run.photoeyes["t_off_s"].max()))
    return max(ends) + 1.0


def resimulate(line: Line, run: Run, params: PlantParams | None = None, seed: int = 0,
               duration_s: float | None = None, record_poses: bool = False) -> Resim:
    """The plant with the run's fish, drops, logged belt speeds and logged device commands (devices home without a
    command log: :func:`unreplayed_devices`).  ``record_poses``: also keep every
    body's pose at 25 Hz in ``sim.poses`` (for a 3D replay of the comparison; off by default, since
    diagnose re-simulates each run many times)."""
    params = params or measured_data_plant()
    duration_s = duration_s or run_duration_s(run)
    if not duration_s <= MAX_RESIM_S:  # the reader refuses such runs; this guards runs made in code
        raise InputError(f"run '{run.id}': re-simulating it would take {duration_s:g} s of simulated time, more than "
                         f"the limit of {MAX_RESIM_S:g} s per re-simulation")
    unlogged = sorted({c.id for c in line.conveyors} - set(run.belts["conveyor_id"].unique()))
    if unlogged:
        raise InputError(f"run '{run.id}': no belt speeds logged for conveyor(s) {', '.join(unlogged)}: every "
                         "conveyor of the line must be in belts.csv")
    rng = np.random.default_rng(run_seed(run.id, seed))
    fish = fish_from_frame(run.fish, run.hours_post_mortem if run.hours_post_mortem is not None else 24.0, rng)
    speed_fn = belt_speed_function(run.belts, [c.id for c in line.conveyors])
    loads: list[tuple] = []

    def log_loads(plant) -> None:
        out = plant.state.outputs
        for cid, force_n in out.belt_load_force_n.items():
            loads.append((out.t_s, cid, force_n, out.belt_load_mass_kg[cid]))

    commands = (command_schedule(run.device_commands, tuple(d.id for d in line.devices))
                if run.device_commands is not None else None)
    sim = simulate_plant(line, fish, speed_fn, duration_s, params=params, stop_when_clear=True, on_step=log_loads,
                         record_poses=record_poses, device_commands=commands)
    return Resim(run.id, sim, pd.DataFrame(loads, columns=["t_s", "conveyor_id", "load_force_n", "load_mass_kg"]))


def not_resimulated(run: Run, error: str) -> Resim:
    """A run whose re-simulation failed or did not happen: empty tables and the reason."""
    empty = SimulatedRun(run.fish, run.tracks.iloc[0:0], run.photoeyes.iloc[0:0], run.belts.iloc[0:0], 0.0, 0.0)
    return Resim(run.id, empty, pd.DataFrame(columns=["t_s", "conveyor_id", "load_force_n", "load_mass_kg"]), error)


def _task(args: tuple) -> Resim:
    line, run, params, seed, record_poses, residuals = args
    try:
        done = resimulate(line, run, params, seed, record_poses=record_poses)
    except SimulationError as exc:
        done = not_resimulated(run, str(exc))
    if residuals:
        done.residuals = residuals_of(Dataset(run.id, "", line, None, [run]), [done])[0]
    return done


def _ignore_sigint() -> None:
    """Pool workers leave Ctrl-C (sent to the whole process group) to the parent, which stops them."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def resim_pool(workers: int | None = None) -> ProcessPoolExecutor | None:
    """Worker processes to keep for several :func:`resimulate_many` calls (each new process pays for
    importing Exudyn); None when one process is asked for.  End it with :func:`stop_pool` (which,
    unlike ``shutdown``, does not wait for re-simulations still running)."""
    workers = max(1, workers or os.cpu_count() or 1)
    if workers == 1:
        return None
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_ignore_sigint)


@contextlib.contextmanager
def pool_for(workers: int | None = None) -> Iterator[ProcessPoolExecutor | None]:
    """A :func:`resim_pool` for the ``with`` block: shut down when it ends, stopped (not waited for) when
    it ends by an error, Ctrl-C or SIGTERM."""
    pool = resim_pool(workers)
    try:
        yield pool
    except BaseException:
        stop_pool(pool)
        raise
    if pool is not None:
        pool.shutdown()


def stop_pool(pool: ProcessPoolExecutor | None, grace_s: float = 2.0) -> None:
    """Cancel what has not started, terminate the worker processes (a running re-simulation is not
    waited for) and shut the pool down; its processes are gone when this returns."""
    if pool is None:
        return
    procs = list((getattr(pool, "_processes", None) or {}).values())  # no public way before Python 3.14
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(grace_s)
        if p.is_alive():
            p.kill()
            p.join(1.0)


def _cost(run: Run) -> float:
    """Rough cost of re-simulating a run (fish x seconds), to start the longest first."""
    return len(run.fish) * run_duration_s(run)


def resimulate_many(line: Line, runs: list[Run], params_per_run: list[PlantParams], workers: int | None = None,
                    seed: int = 0, pool: ProcessPoolExecutor | None = None,
                    record_poses: bool = False, residuals: bool = False) -> list[Resim]:
    """Re-simulate runs (each with its own parameters) in parallel processes, results in input order.

    With ``pool`` (from :func:`resim_pool`) its processes are used; otherwise a pool of ``workers``
    lives for this call.  The longest runs start first, so that workers finish together.
    ``record_poses``: see :func:`resimulate` (the poses are numpy arrays: they come back pickled);
    ``residuals``: each worker also computes its run's residuals (:attr:`Resim.residuals`)."""
    tasks = [(line, r, p, seed, record_poses, residuals) for r, p in zip(runs, params_per_run)]
    done: list[Resim | None] = [None] * len(tasks)
    if pool is None:
        workers = max(1, min(workers or os.cpu_count() or 1, len(tasks)))
        if workers == 1 or len(tasks) == 1:
            try:
                for i, t in enumerate(tasks):
                    done[i] = _task(t)
                    raise_if_signalled()  # a signal whose exception Exudyn's step swallowed
            except STOPS as exc:
                exc.partial = done  # type: ignore[union-attr]  # what finished, None for the rest
                raise
            except SystemError as exc:
                # the signal's exception, raised while Exudyn's step ran Python code, comes out of it wrapped
                if not isinstance(exc.__cause__, STOPS):
                    raise
                exc.__cause__.partial = done  # type: ignore[union-attr]
                raise exc.__cause__ from None
            return done  # type: ignore[return-value]
        own = resim_pool(workers)
        try:
            result = resimulate_many(line, runs, params_per_run, seed=seed, pool=own, record_poses=record_poses,
                                     residuals=residuals)
        except BaseException:
            stop_pool(own)  # a signal or an error: no worker outlives the call, none is waited for
            raise
        own.shutdown()
        return result
    order = sorted(range(len(tasks)), key=lambda i: -_cost(tasks[i][1]))
    futures = {}
    try:
        with deferred_signals():  # the pool starts its processes here: they must not see a Ctrl-C while starting
            futures.update({i: pool.submit(_task, tasks[i]) for i in order})
        for i in range(len(tasks)):
            done[i] = futures[i].result()
    except STOPS as exc:
        for i, f in futures.items():
            f.cancel()
            if done[i] is None and f.done() and not f.cancelled() and f.exception() is None:
                done[i] = f.result()
        exc.partial = done  # type: ignore[union-attr]  # what finished, None for the rest
        raise
    return done  # type: ignore[return-value]


DROP_LEAD_S = 0.05
"""A drop re-simulated alone starts this long before the fish is let go (the plant's first steps settle nothing)."""


def resimulate_drops(line: Line, jobs: list[tuple[Run, list[str], PlantParams]], seed: int = 0,
                     pool: ProcessPoolExecutor | None = None) -> list[dict[str, float]]:
    """Each job's fish dropped again, one at a time and alone, onto the first belt at its logged speed: per job
    (run, fish ids, parameters), each fish's slip as :func:`fishfmu.analysis.observations.drop_slip` reads it (NaN
    where the simulation failed or the slip cannot be read).  What a drop alone shows depends on that fish, its drop
    and the belt only (``drop_rows`` keeps the drops no other fish came near), so simulating it alone is that part
    of the run at a few per cent of its cost; the side it lands on is drawn as :func:`resimulate` draws it."""
    if pool is None:
        return [_drops_task((line, run, ids, params, seed)) for run, ids, params in jobs]
    futures = []
    try:
        with deferred_signals():
            futures = [pool.submit(_drops_task, (line, run, ids, params, seed)) for run, ids, params in jobs]
        return [f.result() for f in futures]
    except STOPS:
        for f in futures:
            f.cancel()
        raise


def _drops_task(args: tuple) -> dict[str, float]:
    line, run, fish_ids, params, seed = args
    rng = np.random.default_rng(run_seed(run.id, seed))  # the same draw of sides as the run's re-simulation
    specs = {f.fish_id: f for f in fish_from_frame(run.fish, run.hours_post_mortem if run.hours_post_mortem
                                                   is not None else 24.0, rng)}
    speed_fn = belt_speed_function(run.belts, [c.id for c in line.conveyors])
    rows = run.fish.set_index("fish_id", drop=False)
    out = {}
    for fid in fish_ids:
        shift = specs[fid].drop_t_s - DROP_LEAD_S  # the run's clock minus the drop's own
        try:
            sim = simulate_plant(line, [dataclasses.replace(specs[fid], drop_t_s=DROP_LEAD_S)],
                                 lambda t, s=shift: speed_fn(t + s), DROP_LEAD_S + DROP_READ_S[1] + 0.05,
                                 params=params, stop_when_clear=False)
        except SimulationError:
            out[fid] = float("nan")
            continue
        read = drop_slip(next(rows.loc[[fid]].itertuples(index=False)), sim.tracks.assign(t_s=sim.tracks["t_s"] + shift),
                         run.belts, line.conveyors[0])
        out[fid] = read[1] if read is not None else float("nan")
    return out


def drive_check(run: Run, loads: pd.DataFrame, conveyor_id: str, drive_parameters: dict | None = None) -> pd.DataFrame:
    """The built-in drive FMU on this belt's logged setpoints and simulated loads.

    Returns t_s, setpoint_mps, measured_mps, model_mps, load_force_n, load_mass_kg at the drive-log times.
    """
    b = run.belts[run.belts["conveyor_id"] == conveyor_id].sort_values("t_s")
    if len(b) < 2:
        return pd.DataFrame({c: pd.Series(dtype=float)
                             for c in ("t_s", "setpoint_mps", "measured_mps", "model_mps", "load_force_n",
                                       "load_mass_kg")})
    t = b["t_s"].to_numpy(float)
    sp = b["setpoint_mps"].to_numpy(float)
    measured = b["speed_mps"].to_numpy(float)
    ld = loads[loads["conveyor_id"] == conveyor_id]
    force = np.interp(t, ld["t_s"].to_numpy(float), ld["load_force_n"].to_numpy(float)) if len(ld) else np.zeros_like(t)
    mass = np.interp(t, ld["t_s"].to_numpy(float), ld["load_mass_kg"].to_numpy(float)) if len(ld) else np.zeros_like(t)
    with open_fmu(builtin_fmu("conveyor_drive")) as fmu:
        model = simulate_drive(fmu, f"drive_{conveyor_id}", t, sp, force, float(measured[0]), drive_parameters)
    return pd.DataFrame({"t_s": t, "setpoint_mps": sp, "measured_mps": measured, "model_mps": model,
                         "load_force_n": force, "load_mass_kg": mass})


def simulate_drive(fmu, name: str, t: np.ndarray, setpoint_mps: np.ndarray, load_force_n: np.ndarray,
                   initial_mps: float, drive_parameters: dict | None = None) -> np.ndarray:
    """Belt speed of the conveyor-drive FMU ``fmu`` (an open archive) at the times ``t``, fed each sample's
    setpoint and load force over the step that follows it, starting at ``initial_mps``."""
    params = {"initial_belt_speed": float(np.clip(initial_mps, -2.0, 2.0)), **(drive_parameters or {})}
    model = np.empty_like(t)
    drive = InProcessFmu(name, fmu, params, start_time_s=float(t[0]))
    try:
        model[0] = drive.get(["belt_speed"])["belt_speed"]
        for i in range(1, len(t)):
            drive.set({"speed_setpoint": float(np.clip(setpoint_mps[i - 1], -2.0, 2.0)),
                       "load_force": float(load_force_n[i - 1])})
            drive.do_step(float(t[i - 1]), float(t[i] - t[i - 1]))
            model[i] = drive.get(["belt_speed"])["belt_speed"]
    finally:
        drive.terminate()
    return model
