"""Schema validation with messages a person can act on.

Every table a user writes (a scenario file, a dataset's ``dataset.toml``) is described by a
pydantic model.  :func:`validate` runs it and turns pydantic's errors into one
:class:`~plant.errors.InputError` naming the file, the dotted key and what is wrong, with a
"did you mean" suggestion for misspelled keys: one line, the most useful problem first (an
unknown key), the others after it in parentheses.
"""

from __future__ import annotations

import difflib
import os
import stat
import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TypeVar

import pydantic

from plant.errors import InputError, echo

M = TypeVar("M", bound=pydantic.BaseModel)


class Strict(pydantic.BaseModel):
    """Base for every user-facing table: unknown keys are errors, values are checked on assignment, and no float
    anywhere in it (a guide's point, a part's offset, a value in a list) may be NaN or infinite.

    A field is documented by ``Field(description=...)``: it shows in docs/scenario-reference.md
    (:mod:`fishfmu.scenario.reference`) and on the served line's variables.  (Not by a docstring under it: pydantic's
    ``use_attribute_docstrings`` reads every model's source at import, a third of a run's own start-up, and no field
    needed it.)"""

    model_config = pydantic.ConfigDict(extra="forbid", validate_assignment=True, frozen=False, allow_inf_nan=False)


def suggest(name: str, known: Iterable[str], *, prefix: str = "", cutoff: float = 0.6, allowed: str | None = None,
            template: str = "; did you mean '{}'?") -> str:
    """The hint to append to a message about a misspelt ``name``: the closest of ``known`` (difflib,
    ``cutoff``) as ``"; did you mean 'x'?"`` (``prefix`` + the name in ``template``); when none is
    close, ``"; <allowed>: a, b"`` listing ``known`` in the order given if ``allowed`` names them,
    else ``""``.  The one home of every "did you mean" in plant and fishfmu.

    >>> suggest("cuont", ["count", "seed"])
    "; did you mean 'count'?"
    >>> suggest("sped", ["speed"], prefix="plant.c1.", template=" (did you mean '{}'?)")
    " (did you mean 'plant.c1.speed'?)"
    >>> suggest("xyz", ["count", "seed"]), suggest("xyz", ["count", "seed"], allowed="allowed keys")
    ('', '; allowed keys: count, seed')
    """
    known = list(known)
    close = difflib.get_close_matches(name, known, n=1, cutoff=cutoff)
    if close:
        return template.format(prefix + close[0])
    return f"; {allowed}: {', '.join(known)}" if allowed and known else ""


class ValueAtKey(ValueError):
    """A cross-field check's failure that names the key to fix (a model validator's error has no key
    of its own: pydantic reports it at the table that holds the fields)."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key
        self.message = message


def _dotted(loc: tuple[Any, ...], prefix: str) -> str:
    out = prefix
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out = f"{out}.{part}" if out else str(part)
    return out


def _known_keys(model: type[pydantic.BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """The keys allowed at ``loc`` (the parent of an unknown key), walking the model's fields."""
    current: Any = model
    for part in loc:
        if isinstance(part, int):
            continue
        if not (isinstance(current, type) and issubclass(current, pydantic.BaseModel)):
            return []
        field = current.model_fields.get(part)
        if field is None:
            return []
        current = _inner_model(field.annotation)
    if isinstance(current, type) and issubclass(current, pydantic.BaseModel):
        return list(current.model_fields)
    return []


def _inner_model(annotation: Any) -> Any:
    """The BaseModel inside ``list[X]``, ``X | None``, ``dict[str, X]``, or the annotation itself."""
    if isinstance(annotation, type) and issubclass(annotation, pydantic.BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()) or ():
        found = _inner_model(arg)
        if found is not None:
            return found
    return None


def describe_error(model: type[pydantic.BaseModel], err: dict[str, Any], prefix: str) -> tuple[str, str]:
    """(dotted key, message) for one pydantic error dict."""
    loc = tuple(err.get("loc", ()))
    raised = err.get("ctx", {}).get("error")
    if isinstance(raised, ValueAtKey):
        parts = tuple(int(k) if k.isdigit() else k for k in raised.key.split("."))  # "conveyors.1.x_m"
        return _dotted(loc + parts, prefix), raised.message
    key = _dotted(loc, prefix)
    kind = err.get("type", "")
    if kind == "extra_forbidden":
        name = str(loc[-1]) if loc else "?"
        known = _known_keys(model, loc[:-1])
        return key, f"unknown key '{name}'{suggest(name, sorted(known), allowed='allowed keys')}"
    if kind == "missing":
        return key, "required key is missing"
    msg = err.get("msg", "invalid value")
    if kind in ("value_error", "assertion_error"):  # our validators' own text, without pydantic's "Value error, "
        msg = str(err.get("ctx", {}).get("error", msg))
    if "input" in err and kind not in ("model_type", "dict_type") and not isinstance(err["input"], dict):
        msg = f"{msg} (got {echo(err['input'])})"
    return key, msg


def validate(model: type[M], data: Any, file: str | Path | None = None, prefix: str = "", strict: bool = False) -> M:
    """Validate ``data`` against ``model``; raise one InputError listing every problem found.

    ``strict``: pydantic's strict mode, every nested table included: a value of the wrong type is refused
    rather than converted (``"2"`` or ``true`` for a float; an integer is still taken for a float)."""
    try:
        return model.model_validate(data, strict=strict or None)
    except pydantic.ValidationError as exc:
        errors = exc.errors(include_url=False)
        # an unknown key first: a misspelt key also makes the right one "missing", and the
        # spelling is what the user has to fix
        errors.sort(key=lambda e: e.get("type") != "extra_forbidden")
        problems = [describe_error(model, e, prefix) for e in errors]
        first_key, first_msg = problems[0]
        more = "; ".join(f"{k}: {m}" for k, m in problems[1:4])
        if len(problems) > 4:
            more += f"; and {len(problems) - 4} more"
        raise InputError(first_msg + (f" (also {more})" if more else ""), file=file, where=first_key or None) from None


MAX_TOML_BYTES = 10 * 1024 * 1024
"""A scenario or dataset.toml is a few kB; 10 MB is far beyond any real one and reads in well under a second."""
MAX_TOML_DEPTH = 32
"""Nesting of tables and arrays in a TOML file: a scenario needs 4 (``fmu[0].parameters.x``); 32 is
far beyond any real file and far below Python's recursion limit (a parser or validator recursing
into 10 000 levels would fail with RecursionError)."""
MAX_CSV_BYTES = 512 * 1024 * 1024
"""One CSV of a measured dataset: 512 MiB, several million rows (a tracks.csv at 25 Hz of 200 fish
over ten minutes is about 200 MB); pandas needs a few times the file's size in memory."""


def read_regular_file(path: str | Path, limit: int, what: str, where: str | None = None,
                      missing: str = "file not found") -> bytes:
    """The bytes of the file at ``path``, a regular file of at most ``limit`` bytes; else an InputError naming it
    (and ``where``, the key that names it).  Opened without blocking (``O_NONBLOCK``) and checked on the open file:
    a FIFO, a device or a folder is refused, never read (a FIFO would block the reader for ever, a device never
    ends)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise InputError(missing, file=path, where=where) from None
    except OSError as exc:  # no permission, a symbolic link loop (ELOOP), ...
        raise InputError(f"cannot read: {exc.strerror or exc}", file=path, where=where) from None
    except ValueError as exc:  # a NUL in the path
        raise InputError(f"not a path: {exc}", file=repr(str(path)), where=where) from None
    _check_regular(fd, path, what, where, limit)
    with os.fdopen(fd, "rb") as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:  # it grew while read
        raise InputError(f"is larger than {limit / 1024**2:.0f} MB, the limit for a {what}", file=path, where=where)
    return data


def _check_regular(fd: int, path: str | Path, what: str, where: str | None, limit: int) -> None:
    """Nothing for a regular file within ``limit``; else ``fd`` is closed and an InputError raised."""
    info = os.fstat(fd)
    problem = None
    if stat.S_ISDIR(info.st_mode):
        problem = f"is a folder, expected a {what}"
    elif not stat.S_ISREG(info.st_mode):
        kind = "a FIFO (named pipe)" if stat.S_ISFIFO(info.st_mode) else "a device or socket"
        problem = f"is {kind}, not a {what} (a regular file): refused without reading it"
    elif info.st_size > limit:
        problem = f"is {info.st_size / 1024**2:.1f} MB; a {what} may be at most {limit / 1024**2:.0f} MB"
    if problem:
        os.close(fd)
        raise InputError(problem, file=path, where=where)


def toml_depth(doc: Any) -> int:
    """How deeply tables and arrays nest in ``doc`` (iterative: any depth is measured)."""
    deepest, stack = 0, [(doc, 0)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, dict):
            children = node.values()
        elif isinstance(node, list):
            children = node
        else:
            continue
        deepest = max(deepest, depth + 1)
        if deepest > MAX_TOML_DEPTH:
            break
        stack.extend((c, depth + 1) for c in children)
    return deepest


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; a missing file or a syntax error becomes an InputError naming the file.

    Limits: :data:`MAX_TOML_BYTES` and :data:`MAX_TOML_DEPTH`."""
    path = Path(path)
    try:
        data = read_regular_file(path, MAX_TOML_BYTES, "TOML file")
        doc = _parse_toml(path, data)
        if toml_depth(doc) > MAX_TOML_DEPTH:
            raise InputError(f"tables and arrays nest more than {MAX_TOML_DEPTH} levels deep (the limit)", file=path)
        return doc
    except RecursionError:
        raise InputError(f"tables and arrays nest too deeply (the limit is {MAX_TOML_DEPTH} levels)",
                         file=path) from None
    except FileNotFoundError:
        raise InputError("file not found", file=path) from None
    except IsADirectoryError:
        raise InputError("is a folder, expected a TOML file", file=path) from None
    except OSError as exc:  # a symbolic link loop (ELOOP), no permission, ...
        raise InputError(f"cannot read: {exc.strerror or exc}", file=path) from None


def _parse_toml(path: Path, data: bytes) -> dict[str, Any]:
    try:
        # a byte-order mark (Windows editors write one) is not part of the TOML text
        return tomllib.loads(data.removeprefix(b"\xef\xbb\xbf").decode("utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"TOML syntax error: {exc}", file=path) from None
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text: {exc}", file=path) from None
