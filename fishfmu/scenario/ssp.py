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
the user's file; what goes wrong with one later is reported naming the SSP and the component, not the copy.

Limits, checked before anything large is read: an ``.ssp`` of at most :data:`MAX_SSP_BYTES`, its zip
directory (member count, names, declared sizes) checked before a member is read, each member read in
chunks (an FMU streamed into the cache while it is hashed, an SSD or SSV read up to :data:`MAX_XML_BYTES`);
components counted against the scenario's room for FMUs before any is copied.  A source is a relative
path inside the archive, or inside the bare ``.ssd``'s folder (no URI scheme, no absolute path, no
``..``), and must be a regular file (a FIFO or device is never opened).
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
import tomllib
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import unquote, urlparse

from lxml import etree

from plant.errors import InputError

from fishfmu.fmu.archive import MAX_MEMBERS, MAX_UNPACKED_BYTES, check_members, open_regular_file
from fishfmu.fmu.build import cache_dir

NS = {
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
}
FMU_TYPE = "application/x-fmu-sharedlibrary"
MAX_XML_BYTES = 64 << 20  # an SSD or SSV larger than this is not a system description
MAX_SSP_BYTES = 1 << 30
"""An ``.ssp`` archive: 1 GiB, as much as its members may unpack to (:data:`fishfmu.fmu.archive.MAX_UNPACKED_BYTES`)."""
_CHUNK_BYTES = 1 << 20
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError, EOFError, OSError, ValueError)
"""What zipfile raises for damaged, encrypted or unsupported members."""


@dataclass(frozen=True)
class SspComponent:
    name: str
    fmu: Path
    parameters: dict[str, Any]
    units: dict[str, str]
    source: str = ""
    """The component's ``source`` as the SSD gives it (for messages: the FMU in the cache is a copy)."""


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
    stop_time_s: float | None = None
    """The default experiment's length (stopTime - startTime), where the SSD gives both."""


class _Source:
    """Where an SSD and the files it names are read from: an SSP archive, or the SSD's folder."""

    def __init__(self, path: Path, archive: zipfile.ZipFile | None) -> None:
        self.path, self.archive = path, archive

    def member(self, uri: str | None, what: str) -> str:
        """A source of the SSD as a relative path inside the archive or inside the SSD's folder (the only kind
        fishfmu follows: no URI scheme, ``file:`` included, no absolute path, no ``..``)."""
        where = "the archive" if self.archive is not None else "the SSD's folder"
        if not uri:
            raise InputError(f"{what}: no source given", file=self.path)
        parsed = urlparse(uri)
        if parsed.scheme or parsed.netloc:
            raise InputError(f"{what} '{uri}': only relative paths inside {where} are supported, not URIs with a "
                             "scheme", file=self.path)
        name = unquote(parsed.path)
        if name.startswith("/") or "\\" in name or "\0" in name or ".." in PurePosixPath(name).parts \
                or name.strip("/") in ("", "."):
            raise InputError(f"{what} '{uri}': only relative paths inside {where} are supported (no absolute path, "
                             "no '..')", file=self.path)
        return name

    def _local(self, uri: str, what: str, kind: str, ext: str) -> Path:
        """A bare SSD's source as a regular file inside its folder (symbolic links followed, and checked too)."""
        name = self.member(uri, what)
        folder = self.path.parent.resolve()
        target = folder / name
        try:
            resolved = target.resolve(strict=True)
        except FileNotFoundError:
            raise InputError(f"{what} '{uri}': {target} not found", file=self.path) from None
        except (OSError, RuntimeError) as exc:  # a symbolic link loop
            raise InputError(f"{what} '{uri}': {target} cannot be read: {getattr(exc, 'strerror', None) or exc}",
                             file=self.path) from None
        if folder not in resolved.parents:
            raise InputError(f"{what} '{uri}' leads out of the SSD's folder (to {resolved}); only relative paths "
                             "inside it are supported", file=self.path)
        try:  # a FIFO or device is refused by its file type (os.stat), never opened for reading
            with open_regular_file(resolved, kind, ext):
                pass
        except InputError as exc:
            raise InputError(f"{what} '{uri}' {exc.message}", file=self.path) from None
        return resolved

    def _info(self, uri: str, what: str, limit: int) -> zipfile.ZipInfo:
        assert self.archive is not None
        try:
            info = self.archive.getinfo(self.member(uri, what))
        except KeyError:
            raise InputError(f"{what} '{uri}' is not in the archive", file=self.path) from None
        if info.is_dir():
            raise InputError(f"{what} '{uri}' is a folder in the archive, not a file", file=self.path)
        if info.file_size > limit:
            raise InputError(f"{what} '{uri}' is {info.file_size} bytes, more than the limit of {limit}",
                             file=self.path)
        return info

    def read(self, uri: str, what: str, limit: int = MAX_XML_BYTES) -> bytes:
        """A whole SSD or SSV (at most ``limit`` bytes, checked before it is read)."""
        if self.archive is None:
            target = self._local(uri, what, "SSV", ".ssv")
            with open_regular_file(target, "SSV", ".ssv") as fh:
                data = fh.read(limit + 1)
        else:
            info = self._info(uri, what, limit)
            try:
                with self.archive.open(info) as fh:
                    data = fh.read(limit + 1)
            except _ZIP_ERRORS as exc:
                raise InputError(f"{what} '{uri}' cannot be read from the archive: {exc}", file=self.path) from None
        if len(data) > limit:
            raise InputError(f"{what} '{uri}' is more than {limit} bytes", file=self.path)
        return data

    def fmu(self, uri: str, component: str) -> Path:
        """The FMU of a component as a file: inside the SSD's folder as it is, or streamed out of the archive into
        the cache (hashed while it is copied: never held in memory whole)."""
        what = f"component '{component}': source"
        if self.archive is None:
            return self._local(uri, what, "FMU", ".fmu")
        info = self._info(uri, what, MAX_UNPACKED_BYTES)
        root = cache_dir() / "ssp"
        root.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".part-", dir=root)
        try:
            digest, copied = hashlib.sha256(), 0
            with os.fdopen(fd, "wb") as out, self.archive.open(info) as src:
                while chunk := src.read(_CHUNK_BYTES):
                    copied += len(chunk)
                    if copied > info.file_size:  # a header that lies about the size
                        raise InputError(f"{what} '{uri}' unpacks to more than the {info.file_size} bytes its "
                                         "header declares", file=self.path)
                    digest.update(chunk)
                    out.write(chunk)
            folder = root / digest.hexdigest()[:24]
            out_path = folder / PurePosixPath(info.filename).name
            if not out_path.is_file():
                folder.mkdir(exist_ok=True)
                os.replace(tmp, out_path)  # readers never see half a file; the same bytes either way
        except _ZIP_ERRORS as exc:
            raise InputError(f"{what} '{uri}' cannot be read from the archive: {exc}", file=self.path) from None
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        return out_path


def _parse(data: bytes, schema: str, path: Path, what: str) -> Any:
    from fmpy.ssp.ssd import validate_tree  # only where an SSP is read: 15 ms of every fishfmu process otherwise
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


INT64_RANGE = (-2**63, 2**63 - 1)


def start_value_problem(value: Any) -> str | None:
    """Why ``value`` cannot be a start value handed to an FMU, or None: finite numbers (integers within 64 bits),
    booleans and strings can.  The one rule for a parameter file's values and the scenario's own (TOML and
    ``--set`` allow ``nan`` and ``inf``, ``1e400`` reads as inf, and TOML has dates and times).

    >>> start_value_problem(0.5), start_value_problem("x")
    (None, None)
    >>> start_value_problem(float("inf"))
    'inf is not a finite number: NaN and infinity cannot be given to an FMU'
    """
    if isinstance(value, (bool, str)):
        return None
    if isinstance(value, int):
        return None if INT64_RANGE[0] <= value <= INT64_RANGE[1] else f"{value} is outside the 64-bit integer range"
    if isinstance(value, float):
        return None if math.isfinite(value) else \
            f"{value} is not a finite number: NaN and infinity cannot be given to an FMU"
    kind = {dict: "a table", list: "an array"}.get(type(value), f"a {type(value).__name__} ({value})")
    return f"is {kind}; a start value is a finite number, a boolean or a string"


def _value(kind: str, text: str | None, where: str, path: Path) -> Any:
    if text is None:
        raise InputError(f"{where}: no value", file=path)
    readers = {"Real": float, "Integer": int, "Boolean": lambda t: {"true": True, "false": False, "1": True,
                                                                    "0": False}[t.strip()], "String": str}
    if kind not in readers:
        raise InputError(f"{where}: {kind} values are not supported (Real, Integer, Boolean and String are)",
                         file=path)
    try:
        value = readers[kind](text)
    except (ValueError, KeyError):
        raise InputError(f"{where}: '{text}' is not a valid {kind}", file=path) from None
    problem = start_value_problem(value)  # the schema's double takes NaN and INF; 1e400 reads as inf
    if problem:
        raise InputError(f"{where}: '{text}': {problem}", file=path)
    return value


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
    for key, value in table.items():  # checked here: the values join the validated scenario by assignment
        problem = start_value_problem(value)
        if problem:
            raise InputError(problem, file=file, where=key)
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


def read_ssp(path: Path, max_components: int | None = None, max_connections: int | None = None) -> SspSystem:
    """The FMU components, connections and parameter values of an ``.ssp`` archive or ``.ssd`` file.

    ``max_components``, ``max_connections``: the room the scenario has left (its limits less its own entries),
    checked before any FMU is copied out of the archive."""
    suffix = path.suffix.lower()
    if suffix not in (".ssp", ".ssd"):
        raise InputError("[system] ssp names neither an SSP archive (.ssp) nor a system description (.ssd)",
                         file=path)
    limits = (max_components, max_connections)
    with open_regular_file(path, "SSP", suffix) as fh:
        if suffix == ".ssd":
            return _read_system(fh.read(MAX_XML_BYTES + 1), _Source(path, None), *limits)
        size = os.fstat(fh.fileno()).st_size
        if size > MAX_SSP_BYTES:
            raise InputError(f"is {size / 1024**2:.0f} MB; an SSP archive may be at most {MAX_SSP_BYTES >> 20} MB",
                             file=path)
        try:  # zipfile reads the directory at the end of the file; members are read one by one, in chunks
            with zipfile.ZipFile(fh) as zf:
                check_members(path, zf, MAX_UNPACKED_BYTES, MAX_MEMBERS)
                source = _Source(path, zf)
                return _read_system(source.read("SystemStructure.ssd", "the archive's SystemStructure.ssd"), source,
                                    *limits)
        except zipfile.BadZipFile as exc:
            raise InputError(f"not a readable zip archive (an SSP is a zip file): {exc}", file=path) from None


def _number(element: Any, attribute: str, default: float, where: str, path: Path) -> float:
    """A finite xs:double attribute (the schema's double takes NaN and INF; 1e400 reads as inf)."""
    text = element.get(attribute)
    value = default if text is None else float(text)  # the schema validated the lexical form
    if not math.isfinite(value):
        raise InputError(f"{where}: {attribute} '{text}' is not a finite number", file=path)
    return value


def _read_system(data: bytes, source: _Source, max_components: int | None = None,
                 max_connections: int | None = None) -> SspSystem:
    path = source.path
    if len(data) > MAX_XML_BYTES:
        raise InputError(f"more than {MAX_XML_BYTES} bytes; not a system description", file=path)
    root = _parse(data, "SystemStructureDescription.xsd", path, "SystemStructure.ssd")
    system = root.find("ssd:System", NS)
    _refuse(system, path)
    elements = list(system.iterfind("ssd:Elements/ssd:Component", NS))
    if max_components is not None and len(elements) > max_components:
        raise InputError(f"the system has {len(elements)} components; the scenario has room for "
                         f"{max(max_components, 0)} more FMUs (its own [[fmu]] and the SSP's count together towards "
                         "the limit)", file=path)
    n_links = len([c for c in system.iterfind("ssd:Connections/ssd:Connection", NS)
                   if c.get("startElement") is not None and c.get("endElement") is not None])
    if max_connections is not None and n_links > max_connections:
        raise InputError(f"the system has {n_links} connections between components; the scenario has room for "
                         f"{max(max_connections, 0)} more (its own [[wiring.connection]] and the SSP's count together "
                         "towards the limit)", file=path)
    components: dict[str, tuple[Any, Path]] = {}
    seen: set[str] = set()
    for c in elements:
        name = c.get("name")
        if name in seen:
            raise InputError(f"component '{name}' appears twice in the system", file=path)
        seen.add(name)
        if c.get("type", FMU_TYPE) != FMU_TYPE:
            raise InputError(f"component '{name}' is of type '{c.get('type')}'; only FMUs ({FMU_TYPE}) are "
                             "supported", file=path)
        if c.get("implementation") not in (None, "CoSimulation", "any"):
            raise InputError(f"component '{name}' asks for implementation '{c.get('implementation')}'; fishfmu "
                             "runs co-simulation FMUs", file=path)
    for c in elements:  # only once every component passed: nothing is copied for a system that is refused
        components[c.get("name")] = (c, source.fmu(c.get("source"), c.get("name")))
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
            where = f"connection {text}: LinearTransformation"
            gain, offset = _number(linear, "factor", 1.0, where, path), _number(linear, "offset", 0.0, where, path)
        connections.append(SspConnection(f"{a}.{c.get('startConnector')}", f"{b}.{c.get('endConnector')}", gain,
                                         offset))
    comps = [SspComponent(n, p, parameters[n], units[n], c.get("source")) for n, (c, p) in components.items()]
    experiment = root.find("ssd:DefaultExperiment", NS)
    length = None
    if experiment is not None and experiment.get("stopTime") is not None:
        where = "DefaultExperiment"
        length = _number(experiment, "stopTime", 0.0, where, path) - _number(experiment, "startTime", 0.0, where, path)
    return SspSystem(system.get("name"), comps, connections, boundary, length)
