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


MAX_MESSAGE_CHARS = 1000
"""An error's message (and its key, row or column) is cut to this many characters: a value echoed from a file (a
list of 10 001 events, a 100 000-character id) must not make a message of megabytes."""
MAX_ECHO_CHARS = 80
"""A value a message echoes (``got ...``) is cut to this many characters."""


def capped(text: str, limit: int = MAX_MESSAGE_CHARS) -> str:
    """``text``, or its first ``limit`` characters and how many there were.

    >>> capped("x" * 60, 40)
    'xxxxxxxxxxxxxxxxxxxxx... (60 characters)'
    """
    if len(text) <= limit:
        return text
    tail = f"... ({len(text)} characters)"
    return text[:max(limit - len(tail), 0)] + tail


def echo(value: object) -> str:
    """``repr(value)`` for a message, at most :data:`MAX_ECHO_CHARS` long (a long list says how many items it has).

    >>> echo(list(range(10001)))
    '[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, ... (10001 items)'
    """
    text = repr(value)
    if len(text) <= MAX_ECHO_CHARS:
        return text
    count = f" ({len(value)} items)" if isinstance(value, (list, tuple, dict, set)) else f" ({len(text)} characters)"
    return text[:MAX_ECHO_CHARS - len(count) - 3] + "..." + count


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
            parts.append(capped(self.where, MAX_ECHO_CHARS * 2))
        prefix = ": ".join(parts)
        message = capped(self.message)
        return one_line(f"{prefix}: {message}" if prefix else message)


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
