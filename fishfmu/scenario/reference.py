"""The scenario file reference, generated from the schema: docs/scenario-reference.md.

One source of truth, as Exudyn generates its item documentation from the item definitions: the
pydantic models that validate a scenario (:class:`fishfmu.scenario.schema.Scenario` and the tables it
holds) are walked recursively, and every key is rendered with its type, unit, default, allowed
range and description (where the default comes from).  A field is documented by
``Field(description=...)`` or by a docstring line under it; the unit comes from the key's suffix
(``_m``, ``_s``, ``_mps``, ``_kg``, ``_n``, ...) or from ``(unit: ...)`` in the description.

Regenerate after changing a model (tests/test_scenario_reference.py checks the file is current)::

    python -m fishfmu.scenario.reference --write

Without ``--write`` the Markdown goes to standard output.
"""

from __future__ import annotations

import re
import sys
import types
import typing
from pathlib import Path
from typing import Any, Literal

import annotated_types
import pydantic
from pydantic.fields import FieldInfo

from fishfmu.scenario.schema import Scenario
from fishfmu.terminal import generated_page

DOC_PATH = Path(__file__).resolve().parents[2] / "docs" / "scenario-reference.md"
COMMAND = "python -m fishfmu.scenario.reference --write"

UNIT_SUFFIXES = (  # longest first: "_rad_s" before "_s"
    ("_rad_s", "rad/s"), ("_mps2", "m/s²"), ("_mps", "m/s"), ("_deg", "°"), ("_rad", "rad"),
    ("_kg", "kg"), ("_m", "m"), ("_s", "s"), ("_h", "h"), ("_n", "N"),
)
UNIT_IN_DESCRIPTION = re.compile(r"\s*\(unit: ([^)]+)\)")

KEY_NAMES = {  # what the free keys of a table are called in the reference
    "fmu[i].parameters": "<variable>",
    "wiring.inputs": "<port>",
    "expect": "<kpi>",
}
DEFAULT_KEY_NAME = "<name>"
INDEX = "[i]"


def unit_of(key: str, description: str | None) -> str:
    """The unit of a key: ``(unit: ...)`` in its description, else its name's suffix, else ``""``."""
    found = UNIT_IN_DESCRIPTION.search(description or "")
    if found:
        return found.group(1).strip()
    for suffix, unit in UNIT_SUFFIXES:
        if key.endswith(suffix):
            return unit
    return ""


def _model(annotation: Any) -> type[pydantic.BaseModel] | None:
    return annotation if isinstance(annotation, type) and issubclass(annotation, pydantic.BaseModel) else None


def _strip_annotated(annotation: Any) -> tuple[Any, list[Any]]:
    """(the bare type, the metadata of any ``Annotated`` around it)."""
    metadata: list[Any] = []
    while typing.get_origin(annotation) is typing.Annotated:
        metadata.extend(annotation.__metadata__)
        annotation = annotation.__origin__
    return annotation, metadata


def _union_args(annotation: Any) -> tuple[Any, ...] | None:
    origin = typing.get_origin(annotation)
    if origin is typing.Union or origin is types.UnionType:
        return typing.get_args(annotation)
    return None


def _without_none(annotation: Any) -> tuple[Any, bool]:
    """(the annotation with ``None`` taken out of a union, whether it was there)."""
    args = _union_args(annotation)
    if args is None or type(None) not in args:
        return annotation, False
    rest = tuple(a for a in args if a is not type(None))
    return (rest[0] if len(rest) == 1 else typing.Union[rest]), True


def type_name(annotation: Any) -> str:
    """A readable type: ``float``, ``list of str``, ``one of "a", "b"``, ``float or bool``."""
    annotation, _ = _strip_annotated(annotation)
    bare, optional = _without_none(annotation)
    if optional:
        return f"{type_name(bare)}, optional"
    args = _union_args(bare)
    if args is not None:
        names = [type_name(a) for a in args]
        return ", ".join(names[:-1]) + " or " + names[-1]
    origin = typing.get_origin(bare)
    if origin is Literal:
        return "one of " + ", ".join(_toml(v) for v in typing.get_args(bare))
    if origin is list:
        (item,) = typing.get_args(bare)
        return "array of tables" if _model(_strip_annotated(item)[0]) else f"list of {type_name(item)}"
    if origin is dict:
        _, value = typing.get_args(bare)
        return "table" if _model(_strip_annotated(value)[0]) else f"table of {type_name(value)}"
    if _model(bare):
        return "table"
    return getattr(bare, "__name__", str(bare))


def _number(value: Any) -> str:
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(value)


def _toml(value: Any) -> str:
    """A default as it would be written in TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{}" if not value else "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    return repr(value)


def _constraints(field: FieldInfo) -> list[Any]:
    """The field's metadata and that of ``Annotated`` types inside it (``Id | None``)."""
    found = list(field.metadata)

    def visit(annotation: Any) -> None:
        annotation, meta = _strip_annotated(annotation)
        for m in meta:  # Annotated[str, Field(...)] holds a FieldInfo with the constraints
            found.extend(m.metadata if isinstance(m, FieldInfo) else [m])
        for arg in _union_args(annotation) or ():
            visit(arg)

    visit(field.annotation)
    return found


def allowed_range(field: FieldInfo, kind: str) -> str:
    """ge/gt/le/lt as ``≥ 0.001, ≤ 0.1``; lengths as characters or entries; a pattern."""
    bounds, lengths, pattern = [], {}, None
    for m in _constraints(field):
        if isinstance(m, annotated_types.Gt):
            bounds.append(f"> {_number(m.gt)}")
        elif isinstance(m, annotated_types.Ge):
            bounds.append(f"≥ {_number(m.ge)}")
        elif isinstance(m, annotated_types.Lt):
            bounds.append(f"< {_number(m.lt)}")
        elif isinstance(m, annotated_types.Le):
            bounds.append(f"≤ {_number(m.le)}")
        elif isinstance(m, annotated_types.MinLen):
            lengths["min"] = m.min_length
        elif isinstance(m, annotated_types.MaxLen):
            lengths["max"] = m.max_length
        if getattr(m, "pattern", None):
            pattern = m.pattern
    parts = list(dict.fromkeys(bounds))
    what = "characters" if kind.split(",")[0] == "str" else "entries"
    if "min" in lengths and "max" in lengths:
        parts.append(f"{lengths['min']} to {lengths['max']} {what}")
    elif "min" in lengths:
        parts.append(f"at least {lengths['min']} {what}")
    elif "max" in lengths:
        parts.append(f"at most {lengths['max']} {what}")
    if pattern:
        parts.append(f"pattern `{pattern}`")
    return ", ".join(parts)


def default_of(field: FieldInfo) -> str:
    if field.is_required():
        return "required"
    value = field.get_default(call_default_factory=True)
    if value is None:
        return "unset"
    if isinstance(value, pydantic.BaseModel):
        return "see below"
    return _toml(value)


def _clean(text: str | None) -> str:
    """reStructuredText of a docstring or description as Markdown on one line."""
    if not text:
        return ""
    text = re.sub(r":\w+:`~?([^`]+)`", lambda m: f"`{m.group(1).split('.')[-1]}`", text)
    text = text.replace("``", "`")
    text = UNIT_IN_DESCRIPTION.sub("", text)
    return " ".join(text.split())


def _cell(text: str) -> str:
    """A table cell: ``|`` escaped; outside code spans, ``<name>`` escaped so it is not read as HTML."""
    parts = text.split("`")
    parts[::2] = [re.sub(r"<(?=[A-Za-z/!?])", "&lt;", p) for p in parts[::2]]
    return "`".join(parts).replace("|", "\\|")


def _see(text: str, heading: str) -> str:
    text = text.rstrip()
    return f"{text}{'' if not text or text.endswith('.') else '.'} See `{heading}`."


def _summary(model: type[pydantic.BaseModel]) -> str:
    doc = model.__doc__ or ""
    return _clean(doc.strip().split("\n\n")[0])


class _Section:
    def __init__(self, heading: str, model: type[pydantic.BaseModel], description: str) -> None:
        self.heading, self.model, self.description = heading, model, description
        self.rows: list[tuple[str, str, str, str, str, str]] = []


def _walk(model: type[pydantic.BaseModel], prefix: str, heading: str, description: str,
          out: list[_Section]) -> None:
    section = _Section(heading, model, description)
    out.append(section)
    below: list[tuple[type[pydantic.BaseModel], str, str, str]] = []
    for attr, field in model.model_fields.items():
        name = field.alias or attr  # the key as written in TOML (from, not from_)
        key = f"{prefix}.{name}" if prefix else name
        bare, _ = _without_none(_strip_annotated(field.annotation)[0])
        origin = typing.get_origin(bare)
        text = _clean(field.description)
        kind = type_name(field.annotation)
        inner = None
        if _model(bare):
            sub = _model(bare)
            inner = (sub, key, f"[{key}]", _summary(sub))
            text = _see(text or _summary(sub), f"[{key}]")
        elif origin is list and _model(_strip_annotated(typing.get_args(bare)[0])[0]):
            sub = _model(_strip_annotated(typing.get_args(bare)[0])[0])
            inner = (sub, key + INDEX, f"[[{key}]]", _summary(sub))
            text = _see(text or _summary(sub), f"[[{key}]]")
        elif origin is dict:
            free = KEY_NAMES.get(key, DEFAULT_KEY_NAME)
            value = _strip_annotated(typing.get_args(bare)[1])[0]
            if _model(value):
                about = f"`{free}`: {text}. " if text else ""  # what the free keys are
                inner = (_model(value), f"{key}.{free}", f"[{key}]", about + _summary(_model(value)))
                text = _see(text or _summary(_model(value)), f"[{key}]")
            else:  # a table of values under names of the user's choosing: one row for them all
                section.rows.append((f"{key}.{free}", type_name(typing.get_args(bare)[1]), "", "",
                                     "", text))
                continue
        section.rows.append((key, kind, unit_of(name, field.description), default_of(field),
                             allowed_range(field, kind), text))
        if inner:
            below.append(inner)
    for sub, sub_prefix, sub_heading, sub_text in below:
        _walk(sub, sub_prefix, sub_heading, sub_text, out)


def sections() -> list[_Section]:
    out: list[_Section] = []
    _walk(Scenario, "", "Tables", _summary(Scenario), out)
    return out


def scenario_reference() -> str:
    """The whole reference as Markdown."""
    lines = [
        "# Scenario file reference",
        "",
        f"*Generated from the schema (fishfmu/scenario.py and the models it uses) by `{COMMAND}`; "
        "do not edit by hand.*",
        "",
        "Every key a scenario file (`scenarios/*.toml`) may hold, generated from the pydantic models that "
        "validate it, so it cannot drift from what `fishfmu run` accepts. An unknown key is an error. "
        f"Keys are written as for `--set`: `{INDEX}` stands for an entry of an array of tables "
        "(`line.conveyors[0].length_m`), `<name>` for a key of your choosing. The unit comes from the "
        "key's suffix (`_m` metre, `_s` second, `_mps` m/s, `_kg`, `_n` newton, `_deg`, `_h` hour); "
        "\"unset\" means the key may be left out and has no value; a range is checked when the file "
        "is read. Checks across keys (a photo-eye on the line, conveyors in flow order, ...) are "
        "described with the keys they concern.",
        "",
    ]
    for section in sections():
        lines += [f"## `{section.heading}`" if section.heading != "Tables" else "## Tables", ""]
        if section.description:
            lines += [section.description, ""]
        lines += ["| key | type | unit | default | range | description |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for key, kind, unit, default, rng, text in section.rows:
            cells = [f"`{key}`", kind, unit, f"`{default}`" if default not in ("", "required", "unset",
                     "see below") else default, rng, text]
            lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return generated_page(scenario_reference(), DOC_PATH, COMMAND, sys.argv[1:] if argv is None else argv)


if __name__ == "__main__":
    raise SystemExit(main())
