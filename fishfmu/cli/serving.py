"""The commands that go with ``fishfmu serve`` (registered on the ``fishfmu`` command in :mod:`fishfmu.cli`):
``hash-password`` for a users file and ``signal-list`` for a PLC's tag table."""

from __future__ import annotations

import getpass
import sys
from pathlib import Path
from typing import Any

import typer

from plant.errors import InputError

from fishfmu.scenario.keys import parse_assignments


def certificates_of(certificate: Path | None, private_key: Path | None, trusted_clients: Path | None,
                    pki: Path | None, user: str | None, other_access: bool) -> Any:
    """The server's certificates as ``serve``'s options give them (None: none), or InputError naming the options
    that do not go together (``other_access``: --users or --allow-anonymous-write was given)."""
    from fishfmu.serve import Certificates  # the option checks only (no asyncua)
    if user is not None and other_access:
        raise InputError("--user (one operator, no anonymous sessions) excludes --users and --allow-anonymous-write")
    given = [certificate, private_key, trusted_clients]
    if pki is not None and any(g is not None for g in given):
        raise InputError("--pki excludes --certificate, --private-key and --trusted-clients (it holds them)")
    if any(g is not None for g in given) and not all(g is not None for g in given):
        raise InputError("--certificate, --private-key and --trusted-clients go together")
    return Certificates(certificate, private_key, trusted_clients) if certificate is not None else None


def hash_password_cmd() -> None:
    """Read a password from the terminal (or one line of stdin) and print its hash for a `serve --users` file."""
    from fishfmu.serve.access import hash_password  # slow (asyncua): imported when the command runs
    password = getpass.getpass("password: ") if sys.stdin.isatty() else sys.stdin.readline().rstrip("\n")
    if not password:
        raise InputError("an empty password is not one", where="password")
    print(hash_password(password))


def signal_list_cmd(
    scenario: Path = typer.Argument(..., help="Scenario file (TOML), as `fishfmu serve` would serve it."),
    out: Path | None = typer.Option(None, "--out", help="The CSV to write (replaced only if fishfmu wrote it); "
                                    "without it, printed."),
    set_: list[str] = typer.Option([], "--set", help="Override a scenario value (repeatable)."),
) -> None:
    """The served line's signal list as CSV for a PLC's tag table: every variable and method of `fishfmu serve`
    with its node id, browse path, direction, type, unit, range, states and description."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    text = commands.signal_list(scenario, out, parse_assignments(set_))
    if out is None:
        sys.stdout.write(text)
