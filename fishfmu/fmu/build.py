"""Build the built-in FMUs (FMI 2.0 co-simulation) from their C sources.

Each FMU lives in ``fishfmu/fmu/sources/<name>/``: ``model.c``, ``README.md`` and ``variables.toml``, the
table of its variables.  That table is the one source of truth: this module writes from it both
``modelDescription.xml`` and the C value references (``model_variables.h``/``.c``), so C and XML
cannot drift apart.  The shared FMI glue and the FMI 2.0 headers (from the fmpy wheel, BSD-2) are
in ``fishfmu/fmu/sources/common/``.  The binary is built with fmpy's CMake project, like ``fmpy compile``
(:mod:`fishfmu.fmu.compile`).

>>> BUILTIN_FMUS
('conveyor_drive', 'singulation_controller')
>>> load_spec("conveyor_drive").variables[0].name
'speed_setpoint'
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import shutil
import tempfile
import tomllib
import uuid
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass
from pathlib import Path

import fmpy

from plant.errors import InputError
from plant.validation import suggest

from fishfmu.fmu.compile import compile_binary

BUILTIN_FMUS = ("conveyor_drive", "singulation_controller")
FMUS_DIR = Path(__file__).parent / "sources"
COMMON_DIR = FMUS_DIR / "common"
GENERATED_HEADER = "model_variables.h"
GENERATED_TABLE = "model_variables.c"

# SI base-unit exponents (and factor) of the units our variables use; written to <UnitDefinitions>.
UNITS: dict[str, tuple[dict[str, int], float]] = {
    "1": ({}, 1.0),
    "s": ({"s": 1}, 1.0),
    "m": ({"m": 1}, 1.0),
    "kg": ({"kg": 1}, 1.0),
    "m/s": ({"m": 1, "s": -1}, 1.0),
    "m/s2": ({"m": 1, "s": -2}, 1.0),
    "N": ({"kg": 1, "m": 1, "s": -2}, 1.0),
    "N.m": ({"kg": 1, "m": 2, "s": -2}, 1.0),
    "W": ({"kg": 1, "m": 2, "s": -3}, 1.0),
    "kg.m2": ({"kg": 1, "m": 2}, 1.0),
    "N.s/m": ({"kg": 1, "s": -1}, 1.0),
    "N.m.s/rad": ({"kg": 1, "m": 2, "s": -1, "rad": -1}, 1.0),
    "rpm": ({"s": -1, "rad": 1}, 2.0 * math.pi / 60.0),
    "s/kg": ({"kg": -1, "s": 1}, 1.0),  # (m/s) per N
}
C_TYPE = {"Real": "TYPE_REAL", "Integer": "TYPE_INTEGER", "Boolean": "TYPE_BOOLEAN"}
C_CAUSALITY = {"parameter": "CAUSALITY_PARAMETER", "calculatedParameter": "CAUSALITY_CALCULATED_PARAMETER",
               "input": "CAUSALITY_INPUT", "output": "CAUSALITY_OUTPUT", "local": "CAUSALITY_LOCAL"}
C_VARIABILITY = {"fixed": "VARIABILITY_FIXED", "tunable": "VARIABILITY_TUNABLE",
                 "discrete": "VARIABILITY_DISCRETE", "continuous": "VARIABILITY_CONTINUOUS"}
INT_RANGE = (-2147483648, 2147483647)


@dataclass(frozen=True)
class Variable:
    """One scalar variable; its value reference is its position in the FMU's table."""

    name: str
    type: str  # Real, Integer, Boolean
    causality: str
    variability: str
    description: str
    unit: str | None = None
    start: float | int | bool | None = None
    min: float | int | None = None
    max: float | int | None = None
    depends_on: tuple[str, ...] = ()
    """Outputs only: inputs this output depends on directly (declared direct feedthrough)."""


@dataclass(frozen=True)
class FmuSpec:
    model_identifier: str
    description: str
    version: str
    sources: tuple[str, ...]  # model-specific C files in fmus/<name>/
    default_experiment: dict[str, float]
    variables: tuple[Variable, ...]


def _default_variability(type_: str, causality: str) -> str:
    if causality in ("parameter", "calculatedParameter"):
        return "fixed"
    return "continuous" if type_ == "Real" else "discrete"


def model_folder(name: str, model_dir: Path | None = None) -> Path:
    """The folder of a model's sources: ``fmus/<name>/`` for a built-in FMU, else ``model_dir``
    (any folder laid out the same way, e.g. the faulty FMUs of the tests)."""
    if model_dir is not None:
        return Path(model_dir)
    if name not in BUILTIN_FMUS:
        raise InputError(f"unknown built-in FMU '{name}' (known: {', '.join(BUILTIN_FMUS)})")
    return FMUS_DIR / name


def load_spec(name: str, model_dir: Path | None = None) -> FmuSpec:
    """Read ``fmus/<name>/variables.toml`` (or ``model_dir/variables.toml``), expanding ``count = n``
    rows into ``name_1 .. name_n``."""
    path = model_folder(name, model_dir) / "variables.toml"
    data = tomllib.loads(path.read_text())
    variables: list[Variable] = []
    for row in data["variable"]:
        count = row.get("count")
        for i in range(1, (count or 1) + 1):
            start = row.get("start")
            variables.append(Variable(
                name=f"{row['name']}_{i}" if count else row["name"],
                type=row["type"],
                causality=row["causality"],
                variability=row.get("variability", _default_variability(row["type"], row["causality"])),
                description=row["description"].replace("{i}", str(i)),
                unit=row.get("unit"),
                start=start[i - 1] if isinstance(start, list) else start,
                min=row.get("min"),
                max=row.get("max"),
                depends_on=tuple(row.get("depends_on", ()))))
    fmu = data["fmu"]
    if fmu["model_identifier"] != name:
        raise InputError(f"model_identifier '{fmu['model_identifier']}' must be the folder name", file=path)
    return FmuSpec(name, fmu["description"], fmu["version"], tuple(fmu["sources"]),
                   dict(fmu["default_experiment"]), tuple(variables))


# ---------------------------------------------------------------- what the build depends on

def fmi2_headers() -> list[Path]:
    """The FMI 2.0 headers, taken from the installed fmpy (its c-code/ ships them, BSD-2), so that
    no third-party file is kept in this repository."""
    c_code = Path(fmpy.__file__).parent / "c-code"
    return [c_code / n for n in ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")]


def _source_files(name: str, model_dir: Path | None = None) -> list[Path]:
    """Every file that goes into the FMU (the shared glue, the model's own files, the FMI headers)."""
    return [p for d in (COMMON_DIR, model_folder(name, model_dir)) for p in sorted(d.rglob("*"))
            if p.is_file() and "__pycache__" not in p.parts] + fmi2_headers()


_digests: dict[tuple, str] = {}
"""source_digest's results in this process, by what they depend on (see :func:`source_digest`)."""


def source_digest(name: str, model_dir: Path | None = None) -> str:
    """Hash of everything the FMU is made from, this generator and the platform included.

    Hashed once per process for as long as the files stay as they were: the result is kept under the
    folders, the file list and each file's size, modification time and inode (a stat each, no read), so
    that a sweep's thousands of preparations and a worker's every task do not read and hash the sources
    again, while an edited or replaced source file is hashed anew."""
    files = [Path(__file__), *_source_files(name, model_dir)]
    stamps = []
    for path in files:
        st = path.stat()
        stamps.append((str(path), st.st_size, st.st_mtime_ns, st.st_ino))
    key = (name, str(model_dir), fmpy.platform, tuple(stamps))
    if key not in _digests:
        h = hashlib.sha256(f"{name}\0{fmpy.platform}\0".encode())
        h.update(Path(__file__).read_bytes() + b"\0")
        for path in files[1:]:
            h.update(path.name.encode() + b"\0")
            h.update(path.read_bytes() + b"\0")
        _digests[key] = h.hexdigest()[:20]
    return _digests[key]


def fmu_guid(name: str, digest: str) -> str:
    """A GUID that stays the same as long as the sources do."""
    return "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, f"https://fishfmu/{name}/{digest}")) + "}"


# ---------------------------------------------------------------- generated files

def _xml_value(value: float | int | bool, type_: str) -> str:
    if type_ == "Boolean":
        return "true" if value else "false"
    return str(int(value)) if type_ == "Integer" else repr(float(value))


def model_description_xml(spec: FmuSpec, guid: str) -> str:
    """The modelDescription.xml text; variable k (1-based index) has value reference k - 1."""
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": spec.model_identifier, "guid": guid,
        "description": spec.description, "version": spec.version, "generationTool": "fishfmu.fmu.build",
        "variableNamingConvention": "flat", "numberOfEventIndicators": "0"})
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": spec.model_identifier, "canHandleVariableCommunicationStepSize": "true",
        "canGetAndSetFMUstate": "false", "canSerializeFMUstate": "false"})
    source_files = ET.SubElement(cs, "SourceFiles")
    for file in c_files(spec):
        ET.SubElement(source_files, "File", {"name": file})
    units = ET.SubElement(root, "UnitDefinitions")
    for unit in sorted({v.unit for v in spec.variables if v.unit}):
        exponents, factor = UNITS[unit]
        base = {k: str(e) for k, e in exponents.items()}
        if factor != 1.0:
            base["factor"] = repr(factor)
        ET.SubElement(ET.SubElement(units, "Unit", {"name": unit}), "BaseUnit", base)
    categories = ET.SubElement(root, "LogCategories")
    for category, text in (("logEvents", "Debug messages (only when logging is on)"),
                           ("logStatusWarning", "Warnings"), ("logStatusError", "Rejected values and failed steps")):
        ET.SubElement(categories, "Category", {"name": category, "description": text})
    ET.SubElement(root, "DefaultExperiment", {
        "startTime": repr(float(spec.default_experiment["start"])),
        "stopTime": repr(float(spec.default_experiment["stop"])),
        "stepSize": repr(float(spec.default_experiment["step"]))})
    model_variables = ET.SubElement(root, "ModelVariables")
    for vr, var in enumerate(spec.variables):
        attrs = {"name": var.name, "valueReference": str(vr), "description": var.description,
                 "causality": var.causality, "variability": var.variability}
        scalar = ET.SubElement(model_variables, "ScalarVariable", attrs)
        type_attrs = {"unit": var.unit} if var.unit else {}
        for key in ("start", "min", "max"):
            value = getattr(var, key)
            if value is not None:
                type_attrs[key] = _xml_value(value, var.type)
        ET.SubElement(scalar, var.type, type_attrs)
    structure = ET.SubElement(root, "ModelStructure")
    outputs = ET.SubElement(structure, "Outputs")
    initial = ET.SubElement(structure, "InitialUnknowns")
    index_of = {var.name: index for index, var in enumerate(spec.variables, start=1)}
    for index, var in enumerate(spec.variables, start=1):
        if var.causality == "output":
            # outputs are functions of the internal state only (no direct feedthrough from inputs)
            # unless the table says otherwise (depends_on)
            deps = " ".join(str(index_of[d]) for d in var.depends_on)
            ET.SubElement(outputs, "Unknown", {"index": str(index), "dependencies": deps})
        if var.causality in ("output", "calculatedParameter"):
            ET.SubElement(initial, "Unknown", {"index": str(index)})
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _c_number(value: float | int | bool | None, default: float) -> str:
    return repr(float(default if value is None else value))


def c_header(spec: FmuSpec, guid: str) -> str:
    """model_variables.h: identifier, GUID and one VR_<NAME> define per variable."""
    lines = [f"/* Generated by fishfmu/fmu_build.py from {spec.model_identifier}/variables.toml: do not edit. */",
             "#ifndef MODEL_VARIABLES_H", "#define MODEL_VARIABLES_H", "",
             f'#define MODEL_IDENTIFIER "{spec.model_identifier}"', f'#define MODEL_GUID "{guid}"',
             f"#define N_VARIABLES {len(spec.variables)}", ""]
    for vr, var in enumerate(spec.variables):
        unit = f" [{var.unit}]" if var.unit else ""
        lines.append(f"#define VR_{var.name.upper()} {vr} /* {var.type} {var.causality}{unit} */")
    return "\n".join(lines + ["", "#endif", ""])


def c_table(spec: FmuSpec) -> str:
    """model_variables.c: name, type, causality, variability, start and range of every variable."""
    rows = []
    for var in spec.variables:
        if var.type == "Boolean":
            lo, hi = 0.0, 1.0
        elif var.type == "Integer":
            lo, hi = INT_RANGE
        else:
            lo, hi = -math.inf, math.inf
        low = "-DBL_MAX" if var.min is None and lo == -math.inf else _c_number(var.min, lo)
        high = "DBL_MAX" if var.max is None and hi == math.inf else _c_number(var.max, hi)
        rows.append(f'    {{"{var.name}", {C_TYPE[var.type]}, {C_CAUSALITY[var.causality]}, '
                    f"{C_VARIABILITY[var.variability]}, {_c_number(var.start, 0.0)}, {low}, {high}}},")
    return "\n".join([f"/* Generated by fishfmu/fmu_build.py from {spec.model_identifier}/variables.toml: "
                      "do not edit. */", "#include <float.h>", "", '#include "fmu_glue.h"', "",
                      "const VariableInfo MODEL_VARIABLES[N_VARIABLES] = {", *rows, "};", ""])


def c_files(spec: FmuSpec) -> list[str]:
    """The C files listed in <SourceFiles>, all flat in the FMU's sources/ folder."""
    return ["fmu_glue.c", *spec.sources, GENERATED_TABLE]


def write_fmu_tree(spec: FmuSpec, guid: str, root: Path, model_dir: Path | None = None) -> None:
    """Lay out an unzipped source FMU: modelDescription.xml, sources/, documentation/."""
    folder = model_folder(spec.model_identifier, model_dir)
    sources = root / "sources"
    docs = root / "documentation"
    sources.mkdir(parents=True)
    (docs / "licenses").mkdir(parents=True)
    (root / "modelDescription.xml").write_text(model_description_xml(spec, guid))
    for path in [*fmi2_headers(), COMMON_DIR / "fmu_glue.h", COMMON_DIR / "fmu_glue.c",
                 *(folder / s for s in spec.sources)]:
        shutil.copy2(path, sources / path.name)
    (sources / GENERATED_HEADER).write_text(c_header(spec, guid))
    (sources / GENERATED_TABLE).write_text(c_table(spec))
    shutil.copy2(folder / "README.md", docs / "README.md")
    shutil.copy2(COMMON_DIR / "FMI2-HEADERS-LICENSE.txt", docs / "licenses" / "fmi2-headers.txt")


# ---------------------------------------------------------------- packing and the cache

def _zip_tree(root: Path, zip_path: Path) -> None:
    with zipfile.ZipFile(zip_path, "w", zipfile.ZIP_DEFLATED) as zf:
        for path in sorted(p for p in root.rglob("*") if p.is_file()):
            zf.write(path, path.relative_to(root).as_posix())


def with_defaults(spec: FmuSpec, defaults: dict[str, float | int | bool]) -> FmuSpec:
    """The spec with changed start values of parameters (baked into the FMU as its defaults)."""
    names = {v.name: v for v in spec.variables}
    for key, value in defaults.items():
        v = names.get(key)
        if v is None or v.causality != "parameter":
            params = [n for n, x in names.items() if x.causality == "parameter"]
            raise InputError(f"'{key}' is not a parameter of {spec.model_identifier}{suggest(key, params)}")
        if (v.min is not None and value < v.min) or (v.max is not None and value > v.max):
            raise InputError(f"{key} = {value} is outside [{v.min}, {v.max}]")
    variables = tuple(dataclasses.replace(v, start=defaults[v.name]) if v.name in defaults else v
                      for v in spec.variables)
    return dataclasses.replace(spec, variables=variables)


def build_fmu(name: str, out_dir: Path, defaults: dict[str, float | int | bool] | None = None,
              model_dir: Path | None = None) -> Path:
    """Build ``<out_dir>/<name>.fmu``: modelDescription, Linux binary and the sources to rebuild it.

    ``defaults``: parameter start values to bake in (an FMU as a vendor would ship it for one line).
    ``model_dir``: build a model from this folder instead of the built-in ``fmus/<name>/``.
    """
    spec = with_defaults(load_spec(name, model_dir), defaults or {})
    digest = source_digest(name, model_dir) + ("" if not defaults else "-" + hashlib.sha256(
        repr(sorted(defaults.items())).encode()).hexdigest()[:8])
    guid = fmu_guid(name, digest)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fmu_path = out_dir / f"{name}.fmu"
    with tempfile.TemporaryDirectory(prefix=f"fishfmu-build-{name}-") as tmp:
        unzipped = Path(tmp) / "fmu"
        write_fmu_tree(spec, guid, unzipped, model_dir)
        compile_binary(unzipped, Path(tmp) / "build", name)
        partial = Path(tmp) / f"{name}.fmu"
        _zip_tree(unzipped, partial)
        shutil.move(partial, out_dir / f".{name}.fmu.{os.getpid()}.part")
        os.replace(out_dir / f".{name}.fmu.{os.getpid()}.part", fmu_path)  # readers never see half a file
    return fmu_path


def cache_dir() -> Path:
    """Where built FMUs are kept: ``$FISHFMU_CACHE`` or ``~/.cache/fishfmu/fmus``."""
    env = os.environ.get("FISHFMU_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "fishfmu" / "fmus"


def builtin_fmu(name: str) -> Path:
    """The built FMU for these sources, built on first use into ``<cache>/<hash of sources>/<name>.fmu``.

    Safe when several processes ask at once: each builds into its own temporary folder and renames
    it into place; the loser of the race drops its copy and uses the winner's.
    """
    model_folder(name)  # rejects unknown names with an InputError
    root = cache_dir()
    final_dir = root / source_digest(name)
    fmu_path = final_dir / f"{name}.fmu"
    if fmu_path.is_file():
        return fmu_path
    root.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{final_dir.name}-", dir=root))
    try:
        build_fmu(name, staging)
        try:
            os.rename(staging, final_dir)
        except OSError:
            if not fmu_path.is_file():
                raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return fmu_path


def install_cached_fmu(name: str, digest: str, data: bytes) -> Path:
    """Put a built FMU made elsewhere (``data``, built from sources hashing to ``digest``) into this
    machine's cache, where :func:`builtin_fmu` finds it without compiling.

    Used by sweep workers that did not build the FMUs (no compiler, or an empty cache).  Refuses
    when this installation's sources hash differently: its plant and FMU code are not the client's.
    """
    local = source_digest(name)
    if local != digest:
        raise InputError(f"built-in FMU '{name}': this installation's sources (digest {local}) differ from the "
                         f"client's ({digest}); install the same fishfmu version on every worker")
    final_dir = cache_dir() / digest
    fmu_path = final_dir / f"{name}.fmu"
    if fmu_path.is_file() and fmu_path.stat().st_size == len(data):
        return fmu_path
    final_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=final_dir, prefix=f".{name}.", suffix=".part")
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)
    os.replace(tmp, fmu_path)  # several worker processes may install at once: each rename is whole
    return fmu_path
