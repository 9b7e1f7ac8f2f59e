"""A run's device command log (``device_commands.csv``): what the PLC told each device, and when.

A line with devices (gates, pushers, diverters) fires them from its controller; which fish a device takes off
depends on when it moves, so a re-simulation that is to compare physics, not a gate that never fires, must move
each device as the line did.  A PLC logs its outputs the way a drive logs its speed: ``t_s, device_id, command``,
one row whenever a device's command changes (1: to the end of its travel, 0: home), starting with every device's
command at the run's start.  A command holds from its row's ``t_s`` until that device's next row.

The plant takes commands once per communication step, at the step's start (as a served line takes a PLC's
outputs on its next scan): :func:`command_schedule` gives each device the last command logged at or before a
step's start, so a command logged between two step starts acts from the next one (up to one step late).

The table's columns are declared with the others in :mod:`plant.contract.measured` (``DEVICE_COMMANDS``); the
checks beyond the format (ids, order, times, values) and the replay are here.

>>> log = pd.DataFrame({"t_s": [0.0, 1.0, 1.5], "device_id": ["gate", "gate", "gate"], "command": [0.0, 1.0, 0.0]})
>>> at = command_schedule(log, ("gate",))
>>> [at(t)["gate"] for t in (0.0, 0.99, 1.0, 1.2, 1.5, 9.0)]
[False, False, True, True, False, False]
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from plant.contract.line import Line
from plant.contract.row_errors import fail_first
from plant.errors import InputError

EPS_S = 1e-9
"""A logged time this close to a step's start counts as at it (fishfmu logs commands at step starts exactly)."""


def check_device_commands(log: pd.DataFrame, path: Path, line: Line, log_end_s: float) -> None:
    """The checks of a read ``device_commands.csv`` beyond its format: every ``device_id`` a device of ``line`` and
    every device of the line in the log, rows in time order (one row per device and time), times within
    ``[0, log_end_s]`` (the drive log's end), commands 0 or 1.  Raises :class:`InputError` naming the row."""
    known = [d.id for d in line.devices]
    t, command = log["t_s"], log["command"]
    checks = (
        (~log["device_id"].isin(known), "device_id", lambda v: f"unknown device_id '{log['device_id'][v].iloc[0]}': "
         f"not a device of the line (devices: {', '.join(known[:12]) or 'none'}{' ...' if len(known) > 12 else ''})"),
        (t < 0, "t_s", lambda v: f"t_s = {t[v].iloc[0]:g} is before the run's start"),
        (t > log_end_s + EPS_S, "t_s", lambda v: f"t_s = {t[v].iloc[0]:g} is after the end of the drive log "
         f"(belts.csv ends at {log_end_s:g} s): a command must fall within the run"),
        (t.diff() < 0, "t_s", lambda v: f"t_s = {t[v].iloc[0]:g} goes back: the log must be in time order"),
        (log.duplicated(["t_s", "device_id"]), "t_s", lambda v: f"device '{log['device_id'][v].iloc[0]}' is "
         f"logged twice at t_s = {t[v].iloc[0]:g}: which command held is ambiguous"),
        (~command.isin([0.0, 1.0]), "command", lambda v: f"command = {command[v].iloc[0]:g}: a device's command is "
         "Boolean, 0 (home) or 1 (to the end of its travel)"),
    )
    for bad, column, message in checks:
        if bad.any():
            fail_first(bad, path, column, message(bad))
    silent = [d for d in known if d not in set(log["device_id"])]
    if silent:
        raise InputError(f"device '{silent[0]}' of the line has no row: log every device's command at the run's "
                         "start (0 if it never moved), or leave the file out if the line did not log its commands",
                         file=path)


def command_schedule(log: pd.DataFrame, device_ids: tuple[str, ...]) -> Callable[[float], dict[str, bool]]:
    """Each device's command at a step starting at ``t``: its last logged command at or before ``t`` (home before
    its first row).  ``log``: a checked ``device_commands.csv`` (rows in time order)."""
    tables = {}
    for d in device_ids:
        rows = log[log["device_id"] == d]
        tables[d] = (rows["t_s"].to_numpy(float), rows["command"].to_numpy(float) >= 0.5)

    def commands(t: float) -> dict[str, bool]:
        out = {}
        for d, (ts, on) in tables.items():
            k = int(np.searchsorted(ts, t + EPS_S, side="right")) - 1
            out[d] = bool(on[k]) if k >= 0 else False
        return out

    return commands
