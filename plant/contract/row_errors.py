"""Where a problem is in a CSV file of a dataset: the row (as a person counts lines in the file: the
header is line 1, blank lines counted) and the column, for :mod:`plant.contract.measured` (the format) and
:mod:`plant.contract.plausibility` (the physics) alike."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import pandas as pd

from plant.errors import InputError


def row_number(index: Any) -> int:
    """Line number in the file of a data row (header is line 1, blank lines counted)."""
    return int(index) + 2


def first_row(mask: pd.Series) -> Any | None:
    """Index label of the first row where ``mask`` is True, or None."""
    m = mask.to_numpy(dtype=bool)
    return mask.index[int(np.argmax(m))] if m.any() else None


def refuse(path: Path, label: Any, column: str, message: str) -> NoReturn:
    """Raise, naming the row with index ``label`` and the column."""
    raise InputError(message, file=path, where=f"row {row_number(label)}, column {column}")


def fail_first(mask: pd.Series, path: Path, column: str, message: str) -> None:
    """Raise, naming the first row where ``mask`` is True (if any)."""
    if mask.any():
        i = int(np.argmax(mask.to_numpy()))
        raise InputError(message, file=path, where=f"row {row_number(mask.index[i])}, column {column}")
