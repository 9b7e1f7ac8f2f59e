"""Dotted keys: how ``--set``, a sweep's ``--param`` and a script's overrides name one value in a scenario's TOML
(``fish.count``, ``fmu[0].parameters.speed_1``), and command-line values read as TOML would read them."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

from plant.errors import InputError


def dotted_parts(key: str) -> list[str | int]:
    """The tables, keys and indices of a dotted key.

    >>> dotted_parts("fmu[0].parameters.speed_1")
    ['fmu', 0, 'parameters', 'speed_1']
    """
    return [int(p[1:-1]) if p.startswith("[") else p for p in re.findall(r"[^.\[\]]+|\[\d+\]", key)]


def set_dotted(data: dict[str, Any], key: str, value: Any, file: str | Path | None = None) -> None:
    """Set ``data['a']['b'][2]['c'] = value`` for ``key = 'a.b[2].c'``, creating tables as needed."""
    parts = dotted_parts(key)
    if not parts:
        raise InputError(f"empty key in override '{key}'", file=file)
    node: Any = data
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(part, int):
            idx = part
            if not isinstance(node, list) or idx >= len(node):
                raise InputError(f"override '{key}': no element {idx} there", file=file)
            if last:
                node[idx] = value
            else:
                node = node[idx]
        else:
            if not isinstance(node, dict):
                raise InputError(f"override '{key}': '{part}' is not inside a table", file=file)
            if last:
                node[part] = value
            else:
                node = node.setdefault(part, {})


def get_dotted(data: dict[str, Any], key: str, overrides: dict[str, Any] | None = None) -> Any:
    """The value of ``key`` (``a.b[2].c``) in a scenario's TOML, or in ``overrides`` if given there."""
    if overrides and key in overrides:
        return overrides[key]
    node: Any = data
    for part in dotted_parts(key):
        if isinstance(part, int):
            idx = part
            if not isinstance(node, list) or idx >= len(node):
                raise InputError(f"'{key}': no element {idx} there")
            node = node[idx]
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            raise InputError(f"'{key}' is not set in the scenario")
    return node


def parse_value(text: str) -> Any:
    """A command-line value as TOML would read it (numbers, booleans, strings, arrays)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_assignments(items: list[str], option: str = "--set") -> dict[str, Any]:
    """``KEY=VALUE`` items of a command-line option as a dict, values read as TOML would read them.

    >>> parse_assignments(["fish.count=30", "run.name = a b"])
    {'fish.count': 30, 'run.name': 'a b'}
    """
    out: dict[str, Any] = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise InputError(f"{option} '{item}': expected KEY=VALUE")
        out[key.strip()] = parse_value(value.strip())
    return out
