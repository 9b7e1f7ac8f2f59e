"""What fishfmu prints on a terminal: literal text, never markup.

Paths, scenario names, FMU messages and error text come from users and tools; rich would read
``[expect]`` as a style tag and ``a:fish:b`` as an emoji code.  Every console here has markup,
emoji codes and highlighting off, and colour is given only through :class:`rich.text.Text` spans,
so what is printed is exactly the text given.
"""

from __future__ import annotations

import sys
from pathlib import Path

from rich.console import Console
from rich.text import Text


def console(stderr: bool = False) -> Console:
    """A console that prints text literally (tables, progress bars and lines alike)."""
    return Console(stderr=stderr, markup=False, emoji=False, highlight=False, soft_wrap=True)


def one_line(message: object) -> str:
    """The message on one line: line breaks (e.g. in an FMU's log text) become ' / '.

    >>> one_line("doStep failed:\\n  setpoint out of range\\n")
    'doStep failed: / setpoint out of range'
    """
    return " / ".join(part.strip() for part in str(message).splitlines() if part.strip())


def labelled(label: str, message: object, style: str) -> Text:
    """``label`` in ``style`` followed by the message, literal."""
    return Text.assemble((label, style), " ", one_line(message))


def print_error(label: str, message: object) -> None:
    """One line on stderr, e.g. ``error: scen.toml: fish.count: ...``."""
    console(stderr=True).print(labelled(f"{label}:", message, "bold red"))


def outcome(ok: bool, message: object) -> Text:
    """``ok`` (green) or ``FAIL`` (red) before an [expect] bound's message."""
    return Text.assemble(("ok  " if ok else "FAIL", "green" if ok else "red"), " ", one_line(message))


def generated_page(text: str, path: Path, command: str, argv: list[str]) -> int:
    """The ``main`` of a reference page generated from the code (the scenario keys, the command line): with
    ``--write`` the page is written to ``path`` (in the repository's docs/), without arguments printed; the exit
    status."""
    if argv == ["--write"]:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        print(f"wrote {path}")
        return 0
    if argv:
        print(f"usage: {command} (or without --write: to standard output)", file=sys.stderr)
        return 2
    sys.stdout.write(text)
    return 0
