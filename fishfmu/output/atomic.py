"""The atomic writers every command uses: a file is written under a temporary name, recorded in
its folder's manifest (:mod:`fishfmu.output.manifest`, where the file writers live) and renamed into
place, so a crash or an interrupt never leaves a half-written file under its final name, and a file
that was there (a hard link to it, a backup's copy) keeps what it held.

A module of its own, below :mod:`fishfmu.output.run_folder` (a command's folder, the one writer of
``run_info.json`` and ``kpis.json``), so that what only needs to write a file (the report, a sweep's tables)
does not import the run's output writer and, through it, the runner.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from fishfmu.output.manifest import write_bytes_atomic, write_file_atomic, write_tree_atomic

__all__ = ["json_safe", "write_bytes_atomic", "write_file_atomic", "write_figure_atomic", "write_json_atomic",
           "write_text_atomic", "write_tree_atomic"]


def write_text_atomic(path: Path, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: Path, data: Any) -> None:
    write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True, allow_nan=False) + "\n")


def write_figure_atomic(path: Path, fig: Any, **savefig: Any) -> bytes:
    """Write the matplotlib figure ``fig`` as the PNG ``path`` (``savefig`` options: dpi, bbox_inches);
    returns its bytes (a report embeds them)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", **savefig)
    data = buf.getvalue()
    write_bytes_atomic(path, data)
    return data


def json_safe(x: Any) -> Any:
    """JSON-safe: NaN/inf -> None, numpy scalars -> Python, tuples -> lists, keys -> str.  Every JSON
    document fishfmu writes from computed numbers goes through this (:func:`write_json_atomic` itself
    refuses NaN, so a value that escaped it is a bug that shows).

    >>> json_safe({1: (np.float64("nan"), np.int64(3), np.bool_(True), 0.5)})
    {'1': [None, 3, True, 0.5]}
    """
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, np.bool_):
        return bool(x)
    return x
