"""SSP import (``[system] ssp``) and parameter files (``[[fmu]] parameter_file``).

An SSP (System Structure and Parameterization, Modelica Association, 1.0) archive holds a
``SystemStructure.ssd`` describing FMU components, the connections between them (optionally with a
linear transformation) and parameter values (inline, or in ``.ssv`` files), with the FMUs under
``resources/``.  A bare ``.ssd`` file names FMUs and ``.ssv`` files relative to itself.

Both are validated against the SSP 1.0 schemas that fmpy ships (:func:`fmpy.ssp.ssd.validate_tree`)
and ``.ssv`` files are read with fmpy's reader.  The system itself is read from the validated tree
here rather than with fmpy's ``read_ssd``: that reader looks for a connection's transformation in the
wrong namespace (``ssd:`` instead of the standard's ``ssc:LinearTransformation``), so it drops the
gain of a conforming file without a word, and it reads archives only.  pyssp-standard (the other SSP
package on the index) does not read connection transformations either.

What is taken: components of type ``application/x-fmu-sharedlibrary`` of the top system, connections
between them with ``ssc:LinearTransformation`` (factor, offset), and parameter bindings (on the system,
names ``component.variable``; on a component, its variable names; ``prefix`` prepended as SSP says).
What is refused with a message: nested systems, signal dictionaries, other component types, mapping
transformations, parameter mappings, Enumeration and Binary values.  Connections to the system's own
connectors are not imported: the plant is not part of the SSP, so its links are stated in ``[wiring]``.

FMUs inside an archive are copied into fishfmu's cache (``<cache>/ssp/<content hash>/``), never next to
the user's file.
"""

from __future__ import annotations

import hashlib
import io
import os
import tempfile
import tomllib
import zipfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import unquote, urlparse

from plant.errors import InputError

NS = {
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
}
FMU_TYPE = "application/x-fmu-sharedlibrary"
MAX_XML_BYTES = 64 << 20  # an SSD or SSV larger than this is not a system description


@dataclass(frozen=True)
class SspComponent:
    name: str
    fmu: Path
    parameters: dict[str, Any]
    units: dict[str, str]


@dataclass(frozen=True)
class SspConnection:
    source: str
    """``component.variable``"""
    target: str
    gain: float | None
    offset: float | None


@dataclass(frozen=True)
class SspSystem:
    name: str
    components: list[SspComponent]
    connections: list[SspConnection]
    boundary: list[str]
    """Connections to the system's own connectors, not imported (the plant's links are in ``[wiring]``)."""


class _Source:
    """Where an SSD and the files it names are read from: an SSP archive, or the SSD's folder."""

    def __init__(self, path: Path, archive: zipfile.ZipFile | None) -> None:
        self.path, self.archive = path, archive

    def member(self, uri: str, what: str) -> str:
        """A relative URI of the SSD as a path inside the archive or below the SSD's folder's view."""
        parsed = urlparse(uri)
        if parsed.scheme not in ("", "file") or parsed.netloc:
            raise InputError(f"{what} '{uri}': only relative paths are supported, not URIs with a scheme",
                             file=self.path)
        name = unquote(parsed.path)
        if self.archive is not None:
            parts = PurePosixPath(name).parts
            if name.startswith("/") or ".." in parts or "\\" in name:
                raise InputError(f"{what} '{uri}' leads out of the archive", file=self.path)
        return name

    def read(self, uri: str, what: str, limit: int = MAX_XML_BYTES) -> bytes:
        name = self.member(uri, what)
        if self.archive is not None:
            try:
                info = self.archive.getinfo(name)
            except KeyError:
                raise InputError(f"{what} '{uri}' is not in the archive", file=self.path) from None
            if info.file_size > limit:
                raise InputError(f"{what} '{uri}' is {info.file_size} bytes, more than the limit of {limit}",
                                 file=self.path)
            with self.archive.open(info) as fh:
                data = fh.read(limit + 1)
            if len(data) > limit:
                raise InputError(f"{what} '{uri}' unpacks to more than {limit} bytes", file=self.path)
            return data
        target = self.path.parent / name
        try:
            size = target.stat().st_size
        except OSError as exc:
            raise InputError(f"{what} '{uri}' ({target}) cannot be read: {exc.strerror}", file=self.path) from None
        if size > limit:
            raise InputError(f"{what} '{uri}' is {size} bytes, more than the limit of {limit}", file=self.path)
        return target.read_bytes()

    def fmu(self, uri: str, component: str) -> Path:
        """The FMU of a component as a file: below the SSD's folder as it is, or copied out of the archive
        into the cache."""
        from fishfmu.fmu.archive import MAX_UNPACKED_BYTES
        from fishfmu.fmu.build import cache_dir
        what = f"component '{component}': source"
        if self.archive is None:
            return (self.path.parent / self.member(uri, what)).resolve()
        data = self.read(uri, what, limit=MAX_UNPACKED_BYTES)
        folder = cache_dir() / "ssp" / hashlib.sha256(data).hexdigest()[:24]
        out = folder / PurePosixPath(self.member(uri, what)).name
        if not out.is_file():
            folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=".part-", dir=folder)
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            os.replace(tmp, out)  # readers never see half a file; the same bytes either way
        return out


def _parse(data: bytes, schema: str, path: Path, what: str) -> Any:
    from lxml import etree
    from fmpy.ssp.ssd import validate_tree
    parser = etree.XMLParser(resolve_entities=False, no_network=True)
    try:
        root = etree.fromstring(data, parser)
        validate_tree(root, schema)
    except etree.XMLSyntaxError as exc:
        raise InputError(f"{what} is not well-formed XML: {exc}", file=path) from None
    except Exception as exc:  # fmpy raises a bare Exception listing the schema errors
        raise InputError(f"{what} does not conform to the SSP 1.0 schema: "
                         f"{' '.join(str(exc).split())[:400]}", file=path) from None
    return root


def _value(kind: str, text: str | None, where: str, path: Path) -> Any:
    if text is None:
        raise InputError(f"{where}: no value", file=path)
    try:
        if kind == "Real":
            return float(text)
        if kind == "Integer":
            return int(text)
        if kind == "Boolean":
            return {"true": True, "false": False, "1": True, "0": False}[text.strip()]
        if kind == "String":
            return text
    except (ValueError, KeyError):
        raise InputError(f"{where}: '{text}' is not a valid {kind}", file=path) from None
    raise InputError(f"{where}: {kind} values are not supported (Real, Integer, Boolean and String are)",
                     file=path)


def _parameter_set(root: Any, path: Path, where: str) -> tuple[dict[str, Any], dict[str, str]]:
    """The values and stated units of an ``ssv:ParameterSet`` element, by parameter name."""
    values, units = {}, {}
    for p in root.iterfind("ssv:Parameters/ssv:Parameter", NS):
        name = p.get("name")
        typed = next(iter(p), None)
        while typed is not None and not isinstance(typed.tag, str):  # skip comments
            typed = typed.getnext()
        kind = typed.tag.rpartition("}")[2] if typed is not None else "?"
        values[name] = _value(kind, typed.get("value") if typed is not None else None,
                              f"{where}: parameter '{name}'", path)
        if kind == "Real" and typed.get("unit"):
            units[name] = typed.get("unit")
    return values, units


def read_parameter_file(file: Path, scenario_file: Path, where: str) -> tuple[dict[str, Any], dict[str, str]]:
    """Start values from an ``.ssv`` (SSP parameter values, validated) or a ``.toml`` table of
    ``variable = value``; and the units an SSV states, by variable."""
    from fishfmu.fmu.archive import open_regular_file
    suffix = file.suffix.lower()
    if suffix not in (".ssv", ".toml"):
        raise InputError(f"{where}: '{file.name}' is neither an SSP parameter-value file (.ssv) nor TOML (.toml)",
                         file=scenario_file)
    with open_regular_file(file, "parameter file", suffix) as fh:
        data = fh.read(MAX_XML_BYTES + 1)
    if len(data) > MAX_XML_BYTES:
        raise InputError(f"more than {MAX_XML_BYTES} bytes; not a parameter file", file=file)
    if suffix == ".ssv":
        return _parameter_set(_parse(data, "SystemStructureParameterValues.xsd", file, "parameter file"), file,
                              "ssv")
    try:
        table = tomllib.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"not valid TOML: {exc}", file=file) from None
    for key, value in table.items():
        if isinstance(value, (dict, list)) or (isinstance(value, float) and value != value):
            raise InputError(f"'{key}': a start value is a number, boolean or string", file=file)
    return table, {}


def _bindings(element: Any, source: _Source, owner: str) -> tuple[dict[str, Any], dict[str, str]]:
    """The parameter values bound to a system or component (names with their binding's prefix)."""
    values: dict[str, Any] = {}
    units: dict[str, str] = {}
    for i, b in enumerate(element.iterfind("ssd:ParameterBindings/ssd:ParameterBinding", NS)):
        where = f"{owner}: parameter binding {i + 1}"
        if b.find("ssd:ParameterMapping", NS) is not None:
            raise InputError(f"{where}: parameter mappings (SSM) are not supported; name the variables in the "
                             "parameter set", file=source.path)
        if b.get("type", "application/x-ssp-parameter-set") != "application/x-ssp-parameter-set":
            raise InputError(f"{where}: type '{b.get('type')}' is not supported (SSV parameter sets are)",
                             file=source.path)
        if b.get("source") is not None:
            if b.get("sourceBase", "SSD") != "SSD":
                raise InputError(f"{where}: sourceBase '{b.get('sourceBase')}' is not supported", file=source.path)
            root = _parse(source.read(b.get("source"), f"{where}: source"), "SystemStructureParameterValues.xsd",
                          source.path, f"{where}: '{b.get('source')}'")
            sets = [root]
        else:
            sets = list(b.iterfind("ssd:ParameterValues/ssv:ParameterSet", NS))
        prefix = b.get("prefix", "")
        for s in sets:
            v, u = _parameter_set(s, source.path, where)
            values.update({prefix + k: x for k, x in v.items()})
            units.update({prefix + k: x for k, x in u.items()})
    return values, units


def _refuse(system: Any, path: Path) -> None:
    if system.find("ssd:Elements/ssd:System", NS) is not None:
        raise InputError("nested systems are not supported; give the FMUs of one system", file=path)
    if system.find("ssd:Elements/ssd:SignalDictionaryReference", NS) is not None or \
            system.find("ssd:SignalDictionaries", NS) is not None:
        raise InputError("signal dictionaries are not supported; connect the FMUs' variables directly", file=path)


def read_ssp(path: Path) -> SspSystem:
    """The FMU components, connections and parameter values of an ``.ssp`` archive or ``.ssd`` file."""
    from fishfmu.fmu.archive import MAX_MEMBERS, MAX_UNPACKED_BYTES, check_members, open_regular_file
    suffix = path.suffix.lower()
    if suffix not in (".ssp", ".ssd"):
        raise InputError("[system] ssp names neither an SSP archive (.ssp) nor a system description (.ssd)",
                         file=path)
    with open_regular_file(path, "SSP", suffix) as fh:
        if suffix == ".ssd":
            return _read_system(fh.read(MAX_XML_BYTES + 1), _Source(path, None))
        blob = io.BytesIO(fh.read())
    try:
        with zipfile.ZipFile(blob) as zf:
            check_members(path, zf, MAX_UNPACKED_BYTES, MAX_MEMBERS)
            return _read_system(_Source(path, zf).read("SystemStructure.ssd", "the archive's SystemStructure.ssd"),
                                _Source(path, zf))
    except zipfile.BadZipFile as exc:
        raise InputError(f"not a readable zip archive (an SSP is a zip file): {exc}", file=path) from None


def _read_system(data: bytes, source: _Source) -> SspSystem:
    path = source.path
    if len(data) > MAX_XML_BYTES:
        raise InputError(f"more than {MAX_XML_BYTES} bytes; not a system description", file=path)
    root = _parse(data, "SystemStructureDescription.xsd", path, "SystemStructure.ssd")
    system = root.find("ssd:System", NS)
    _refuse(system, path)
    components: dict[str, tuple[Any, Path]] = {}
    for c in system.iterfind("ssd:Elements/ssd:Component", NS):
        name = c.get("name")
        if name in components:
            raise InputError(f"component '{name}' appears twice in the system", file=path)
        if c.get("type", FMU_TYPE) != FMU_TYPE:
            raise InputError(f"component '{name}' is of type '{c.get('type')}'; only FMUs ({FMU_TYPE}) are "
                             "supported", file=path)
        if c.get("implementation") not in (None, "CoSimulation", "any"):
            raise InputError(f"component '{name}' asks for implementation '{c.get('implementation')}'; fishfmu "
                             "runs co-simulation FMUs", file=path)
        components[name] = (c, source.fmu(c.get("source"), name))
    parameters: dict[str, dict[str, Any]] = {n: {} for n in components}
    units: dict[str, dict[str, str]] = {n: {} for n in components}
    values, stated = _bindings(system, source, f"system '{system.get('name')}'")
    for key, value in values.items():
        comp, dot, var = key.partition(".")
        if not dot or comp not in components:
            raise InputError(f"system parameter '{key}' names no component (components: "
                             f"{', '.join(components) or 'none'})", file=path)
        parameters[comp][var] = value
        if key in stated:
            units[comp][var] = stated[key]
    for name, (c, _) in components.items():
        v, u = _bindings(c, source, f"component '{name}'")
        parameters[name].update(v)  # a component's own binding is the more specific one
        units[name].update(u)
    connections, boundary = [], []
    for c in system.iterfind("ssd:Connections/ssd:Connection", NS):
        a, b = c.get("startElement"), c.get("endElement")
        text = f"{a or system.get('name')}.{c.get('startConnector')} -> {b or system.get('name')}.{c.get('endConnector')}"
        if a is None or b is None:
            boundary.append(text)
            continue
        for end in (a, b):
            if end not in components:
                raise InputError(f"connection {text}: '{end}' is not a component of the system", file=path)
        linear = c.find("ssc:LinearTransformation", NS)
        if linear is None and len([e for e in c if isinstance(e.tag, str) and e.tag.endswith("Transformation")]):
            raise InputError(f"connection {text}: mapping transformations are not supported (linear ones are)",
                             file=path)
        gain = offset = None
        if linear is not None:
            gain, offset = float(linear.get("factor", 1.0)), float(linear.get("offset", 0.0))
        connections.append(SspConnection(f"{a}.{c.get('startConnector')}", f"{b}.{c.get('endConnector')}", gain,
                                         offset))
    comps = [SspComponent(n, p, parameters[n], units[n]) for n, (_, p) in components.items()]
    return SspSystem(system.get("name"), comps, connections, boundary)
