"""The kinds of failure a user can meet, as exceptions (the command line maps them to its exit codes:
``fishfmu.cli.exit_codes``).

`InputError` is anything wrong with what the user gave (a file, a key, a row, a column).
`SimulationError` is a run that could not go on (a blow-up, an FMU that failed).
`SystemDependencyError` is a machine that lacks a system package fishfmu needs (a shared library Exudyn
loads, a C compiler for the built-in FMUs): the run could not be made and nothing the user gave is wrong.
Anything else is a bug.  Each carries a message meant to be read by a person, naming where the problem is.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

_LINE_BREAKING = {c: repr(chr(c))[1:-1] for c in [*range(32), 127, 0x85, 0x2028, 0x2029]}


def one_line(text: str) -> str:
    """``text`` with line breaks and other control characters escaped (a key or value from a file
    may hold them): a message stays one line.

    >>> print(one_line("key" + chr(10) + "with a break"))
    key\\nwith a break
    """
    return text.translate(_LINE_BREAKING)


@dataclass
class InputError(Exception):
    """Bad input: names the file (if any), the location inside it (key, row, column) and what is wrong."""

    message: str
    file: str | Path | None = None
    where: str | None = None

    def __str__(self) -> str:
        parts = []
        if self.file is not None:
            parts.append(str(self.file))
        if self.where:
            parts.append(self.where)
        prefix = ": ".join(parts)
        return one_line(f"{prefix}: {self.message}" if prefix else self.message)


@dataclass
class SimulationError(Exception):
    """A run that stopped: names the simulated time and what happened (which fish, which FMU)."""

    message: str
    time_s: float | None = None

    def __str__(self) -> str:
        if self.time_s is None:
            return one_line(self.message)
        return one_line(f"at t = {self.time_s:.3f} s: {self.message}")


@dataclass
class SystemDependencyError(Exception):
    """The machine lacks something pip cannot install: names what is missing and the Debian/Ubuntu
    package that provides it.  Neither bad input (changing the user's files will not help) nor a bug."""

    message: str

    def __str__(self) -> str:
        return one_line(self.message)
