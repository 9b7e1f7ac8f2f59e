"""Open any user's FMU file safely: check the archive before unpacking it, then its modelDescription.

An FMU is a zip file from somewhere else.  Before anything is written, :func:`open_fmu` rejects
members that would land outside the unpack folder (absolute paths, ``..``, backslashes, drive
letters, symlinks) and archives that are too large or have too many members (zip bombs); while
unpacking it counts the bytes actually written, so that a member whose header lies about its size
is caught too.  Everything goes into one fresh temporary folder, removed on exit and on every
error.  (The FMU's native code still runs with our rights once loaded: this checks the file, it
does not sandbox the model.)

Every problem is an :class:`~plant.errors.InputError` naming the file and the member or variable.
"""

from __future__ import annotations

import os
import platform
import re
import shutil
import stat
import tempfile
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Protocol

from fmpy import read_model_description

from plant.errors import InputError
from plant.validation import suggest

from fishfmu.fmu.clocks import clock_attributes, clock_problem

MAX_UNPACKED_BYTES = 1 << 30  # 1 GiB: far above any real FMU, far below filling a disk
MAX_MEMBERS = 20_000
LINUX_BINARY_DIR = "binaries/linux64"
"""Where an FMI 2.0 FMU keeps its Linux library."""
FMI3_PLATFORMS = {"x86_64": "x86_64-linux", "amd64": "x86_64-linux", "aarch64": "aarch64-linux",
                  "arm64": "aarch64-linux"}


def binary_dir(fmi_version: str) -> str:
    """The archive folder of this machine's library: ``binaries/linux64`` (FMI 2.0) or ``binaries/<arch>-linux``
    (FMI 3.0's platform tuple)."""
    if fmi_version.startswith("3"):
        return f"binaries/{FMI3_PLATFORMS.get(platform.machine().lower(), platform.machine().lower() + '-linux')}"
    return LINUX_BINARY_DIR
_CHUNK_BYTES = 1 << 20
_DRIVE_LETTER = re.compile(r"^[A-Za-z]:")


@dataclass(frozen=True)
class FmuVariable:
    """What an importer needs to know about one variable to connect it."""

    name: str
    causality: str  # parameter, calculatedParameter, input, output, local, independent
    type: str
    """Real, Integer, Boolean, String or Enumeration (FMI 3.0's types mapped onto them, see :data:`FMI3_TYPES`);
    an FMI 3.0 Binary, Clock or array variable keeps that kind and connects to nothing."""
    variability: str
    value_reference: int
    unit: str | None
    """The variable's unit, or its declared type's (FMI lets a type carry it: ``<Real declaredType="Length"/>``)."""
    start: Any
    unit_base: tuple[float, ...] | None = None
    """The unit's definition in SI base units, (kg, m, s, A, K, mol, cd, rad exponents, factor, offset), where the
    modelDescription gives one: "m/s" and "m.s-1" are the same unit."""
    initial: str | None = None
    """exact, approx or calculated (FMI 2.0 section 2.2.7); None where FMI has none."""
    fmi_type: str | None = None
    """The type as the modelDescription names it (FMI 3.0: Float64, Int32, UInt8, ...): which get and set call."""


BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
FMI3_TYPES = {"Float32": "Real", "Float64": "Real", "Int8": "Integer", "UInt8": "Integer", "Int16": "Integer",
              "UInt16": "Integer", "Int32": "Integer", "UInt32": "Integer", "Int64": "Integer", "UInt64": "Integer",
              "Boolean": "Boolean", "String": "String", "Enumeration": "Enumeration", "Binary": "Binary",
              "Clock": "Clock"}
"""FMI 3.0 types onto the kinds of values fishfmu passes (Python float, int, bool, str): every float a Real,
every integer width an Integer (an int holds each exactly), Binary and Clock kept apart (not connectable)."""


def variables_of(md: Any) -> dict[str, FmuVariable]:
    """Every variable of a modelDescription (fmpy's), by name, with its unit from its declared type where it has
    none of its own and that unit's definition in base units."""
    bases = {u.name: tuple(float(getattr(u.baseUnit, k)) for k in (*BASE_UNITS, "factor", "offset"))
             for u in md.unitDefinitions if u.baseUnit is not None}
    out = {}
    fmi3 = md.fmiVersion.startswith("3")
    for v in md.modelVariables:
        unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None) or None
        kind = FMI3_TYPES.get(v.type, v.type) if fmi3 else v.type
        if fmi3 and getattr(v, "dimensions", None):
            kind = "Array"  # an array variable: fishfmu passes scalars
        out[v.name] = FmuVariable(v.name, v.causality, kind, v.variability, v.valueReference, unit, v.start,
                                  bases.get(unit) if unit else None, v.initial, v.type)
    return out


class DescribedFmu(Protocol):
    """What parameter and wiring checks read of an FMU: its file and its variables (an
    :class:`OpenedFmu` or a :class:`fishfmu.cosim.preflight.FmuDescription`)."""

    path: Path
    variables: dict[str, FmuVariable]


@dataclass(frozen=True)
class OpenedFmu:
    """An unpacked, checked FMI 2.0 or 3.0 co-simulation FMU; ``unzip_dir`` exists inside ``open_fmu`` only."""

    path: Path
    unzip_dir: Path
    model_description: Any  # fmpy.model_description.ModelDescription
    variables: dict[str, FmuVariable]

    @property
    def model_identifier(self) -> str:
        return self.model_description.coSimulation.modelIdentifier


def _member_problem(info: zipfile.ZipInfo) -> str | None:
    """Why this member must not be unpacked, or None when it is harmless."""
    name = info.filename
    if "\\" in name:
        return "contains a backslash"
    if name.startswith("/") or _DRIVE_LETTER.match(name):
        return "is an absolute path"
    if ".." in PurePosixPath(name).parts:
        return "climbs out of the archive with '..'"
    if "\0" in name or name.strip("/") == "":
        return "has an empty or invalid name"
    mode = info.external_attr >> 16  # Unix mode when the archive was made on Unix, else 0
    if stat.S_ISLNK(mode):
        return "is a symbolic link"
    if stat.S_IFMT(mode) and not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        return "is not a regular file or folder"
    return None


def check_members(path: Path, zf: zipfile.ZipFile, max_unpacked_bytes: int, max_members: int) -> None:
    members = zf.infolist()
    if len(members) > max_members:
        raise InputError(f"archive has {len(members)} members, more than the limit of {max_members}", file=path)
    seen: set[str] = set()
    for info in members:
        problem = _member_problem(info)
        if problem:
            raise InputError(f"archive member '{info.filename}' {problem}; refusing to unpack", file=path)
        key = info.filename.rstrip("/")
        if key in seen:
            raise InputError(f"archive member '{info.filename}' appears twice", file=path)
        seen.add(key)
    declared = sum(info.file_size for info in members)
    if declared > max_unpacked_bytes:
        raise InputError(f"archive would unpack to {declared} bytes, more than the limit of {max_unpacked_bytes} "
                         "(zip bomb?)", file=path)


def _unpack(path: Path, zf: zipfile.ZipFile, target: Path, max_unpacked_bytes: int) -> None:
    """Write every member below ``target``, counting real bytes (headers may lie about sizes)."""
    root = target.resolve()
    written = 0
    for info in zf.infolist():
        dest = (root / info.filename).resolve()
        if dest != root and root not in dest.parents:  # belt and braces after _member_problem
            raise InputError(f"archive member '{info.filename}' would be written outside the folder", file=path)
        if info.is_dir():
            dest.mkdir(parents=True, exist_ok=True)
            continue
        dest.parent.mkdir(parents=True, exist_ok=True)
        member_bytes = 0
        with zf.open(info) as src, open(dest, "xb") as out:
            while chunk := src.read(_CHUNK_BYTES):
                member_bytes += len(chunk)
                written += len(chunk)
                if member_bytes > info.file_size:
                    raise InputError(f"archive member '{info.filename}' unpacks to more than the {info.file_size} "
                                     "bytes its header declares", file=path)
                if written > max_unpacked_bytes:
                    raise InputError(f"archive unpacks to more than the limit of {max_unpacked_bytes} bytes "
                                     f"(at member '{info.filename}'; zip bomb?)", file=path)
                out.write(chunk)


def _read_checked_description(path: Path, unzip_dir: Path) -> Any:
    if not (unzip_dir / "modelDescription.xml").is_file():
        raise InputError("no modelDescription.xml at the top of the archive (not an FMU?)", file=path)
    try:
        md = read_model_description(str(unzip_dir), validate=True)
    except Exception as exc:  # fmpy raises ValidationError, lxml errors, ValueError...
        reason = "; ".join(line.strip(" -\t") for line in str(exc).splitlines() if line.strip(" -\t"))
        raise InputError(f"invalid modelDescription.xml: {reason}", file=path) from exc
    if md.fmiVersion not in ("2.0", "3.0"):
        raise InputError(f"modelDescription.xml is FMI {md.fmiVersion}; FMI 2.0 and 3.0 are supported", file=path)
    if md.coSimulation is None:
        kind = "scheduled execution" if getattr(md, "scheduledExecution", None) else "model exchange"
        raise InputError(f"the FMU offers no co-simulation interface ({kind} only); export it for co-simulation",
                         file=path)
    where = binary_dir(md.fmiVersion)
    identifier_problem = model_identifier_problem(md.coSimulation.modelIdentifier)
    if identifier_problem:
        raise InputError(f"modelDescription.xml: CoSimulation modelIdentifier {md.coSimulation.modelIdentifier!r} "
                         f"{identifier_problem}; it must be a plain file name (the library is "
                         f"{where}/<modelIdentifier>.so inside the archive)", file=path)
    binary = unzip_dir / where / f"{md.coSimulation.modelIdentifier}.so"
    if not binary.is_file():
        found = sorted(p.name for p in (unzip_dir / "binaries").iterdir()) if (unzip_dir / "binaries").is_dir() else []
        raise InputError(f"no Linux binary {where}/{binary.name} in the archive (binaries for: "
                         f"{', '.join(found) or 'none'}); rebuild or re-export the FMU for {where.split('/')[1]}",
                         file=path)
    problem = binary_problem(binary)
    if problem:
        raise InputError(f"archive member '{where}/{binary.name}' {problem}; rebuild or re-export the FMU "
                         f"for Linux on {platform.machine()}", file=path)
    if md.fmiVersion == "3.0":
        _refuse_fmi3_features(md, path, unzip_dir)
    return md


def _refuse_fmi3_features(md: Any, path: Path, unzip_dir: Path) -> None:
    """What fishfmu's master does not do with an FMI 3.0 FMU, refused with the reason: a clock it does not tick
    (:func:`fishfmu.fmu.clocks.clock_problem`; periodic input clocks of an FMU with event mode it does)."""
    if not any(v.type == "Clock" for v in md.modelVariables):
        return
    event_mode = bool(md.coSimulation is not None and getattr(md.coSimulation, "hasEventMode", False))
    for name, attrs in clock_attributes(unzip_dir).items():
        problem = clock_problem(attrs, event_mode)
        if problem:
            raise InputError(f"clock '{name}' is {problem}; fishfmu ticks periodic input clocks of FMUs with event "
                             "mode only", file=path)


_IDENTIFIER = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+\-]*")
MAX_IDENTIFIER_CHARS = 200


def model_identifier_problem(identifier: Any) -> str | None:
    """Why ``identifier`` cannot name the FMU's library safely, or None for a plain file name.

    fmpy loads ``binaries/linux64/<modelIdentifier>.so`` joined to the unpack folder: an absolute
    identifier, ``..`` or a path separator would load a library from anywhere on the machine.

    >>> model_identifier_problem("conveyor_drive") is None
    True
    >>> model_identifier_problem("../../../tmp/evil")
    "contains '..'"
    >>> model_identifier_problem("/tmp/evil")
    'is an absolute path'
    """
    if not isinstance(identifier, str) or identifier == "":
        return "is empty"
    if "\0" in identifier:
        return "contains a NUL character"
    if identifier.startswith(("/", "\\")) or _DRIVE_LETTER.match(identifier):
        return "is an absolute path"
    if ".." in identifier:
        return "contains '..'"
    for sep in ("/", "\\"):
        if sep in identifier:
            return f"contains a path separator {sep!r}"
    if len(identifier) > MAX_IDENTIFIER_CHARS:
        return f"is longer than {MAX_IDENTIFIER_CHARS} characters"
    if not _IDENTIFIER.fullmatch(identifier):
        return "contains characters other than letters, digits and _ . + - (or starts with one of . + -)"
    return None


def library_path(fmu: OpenedFmu) -> Path:
    """The FMU's shared library inside its unpack folder, checked right before it is loaded.

    The modelIdentifier is checked again (an ``OpenedFmu`` may have been built or pickled
    elsewhere) and the resolved path of the library must lie inside the resolved unpack folder
    (no symbolic link or identifier leads out of it); else an InputError naming the FMU file.
    """
    identifier = fmu.model_identifier
    problem = model_identifier_problem(identifier)
    if problem:
        raise InputError(f"modelDescription.xml: CoSimulation modelIdentifier {identifier!r} {problem}; refusing to "
                         "load a library from outside the archive", file=fmu.path)
    root = Path(fmu.unzip_dir).resolve()
    where = binary_dir(fmu.model_description.fmiVersion)
    binary = (root / where / f"{identifier}.so").resolve()
    if root not in binary.parents:
        raise InputError(f"archive member '{where}/{identifier}.so' resolves to {binary}, outside the "
                         "unpacked archive; refusing to load it", file=fmu.path)
    if not binary.is_file():
        raise InputError(f"archive member '{where}/{identifier}.so' is missing from the unpacked archive",
                         file=fmu.path)
    return binary


ELF_MACHINES = {3: "x86 (32-bit)", 40: "ARM (32-bit)", 62: "x86_64", 183: "aarch64", 243: "RISC-V", 21: "PowerPC64"}
THIS_MACHINE = {"x86_64": 62, "amd64": 62, "aarch64": 183, "arm64": 183, "riscv64": 243, "ppc64le": 21}


def binary_problem(binary: Path) -> str | None:
    """Why this file cannot be a shared library for this machine (from its header), or None."""
    with open(binary, "rb") as fh:
        return header_problem(fh.read(20))


def header_problem(head: bytes) -> str | None:
    """Why a file starting with ``head`` (20 bytes) cannot be a shared library for this machine.

    >>> header_problem(b"MZ" + bytes(18))
    'is a Windows binary (PE), not a Linux shared library'
    >>> header_problem(b"\\x7fELF\\x01\\x01" + bytes(14))
    'is a 32-bit ELF file; a 64-bit one is needed'
    """
    if head[:2] == b"MZ":
        return "is a Windows binary (PE), not a Linux shared library"
    if head[:4] in (b"\xfe\xed\xfa\xcf", b"\xcf\xfa\xed\xfe", b"\xca\xfe\xba\xbe"):
        return "is a macOS binary (Mach-O), not a Linux shared library"
    if len(head) < 20 or head[:4] != b"\x7fELF":
        return "is not a shared library (no ELF header)"
    if head[4] != 2:
        return "is a 32-bit ELF file; a 64-bit one is needed"
    if head[5] != 1:
        return "is a big-endian ELF file; this machine is little-endian"
    e_type = int.from_bytes(head[16:18], "little")
    if e_type != 3:  # ET_DYN
        return f"is an ELF file of type {e_type}, not a shared library"
    machine = int.from_bytes(head[18:20], "little")
    expected = THIS_MACHINE.get(platform.machine().lower())
    if expected is not None and machine != expected:
        return (f"is built for {ELF_MACHINES.get(machine, f'ELF machine {machine}')}; this machine is "
                f"{platform.machine()}")
    return None


@contextmanager
def open_fmu(path: str | Path, *, max_unpacked_bytes: int = MAX_UNPACKED_BYTES,
             max_members: int = MAX_MEMBERS) -> Iterator[OpenedFmu]:
    """Check, unpack into a temporary folder and describe an FMI 2.0 or 3.0 co-simulation FMU.

    The folder is removed when the ``with`` block ends or any check fails.
    """
    path = Path(path)
    with open_regular_file(path) as fh:
        if not zipfile.is_zipfile(fh):
            raise InputError("not a zip archive (an FMU is a zip file)", file=path)
        with _unpacked(path, fh, max_unpacked_bytes, max_members) as fmu:
            yield fmu


@contextmanager
def open_regular_file(path: Path, what: str = "FMU", ext: str = ".fmu") -> Iterator[Any]:
    """``path`` opened for reading, if it is a regular file (following symbolic links); else an
    InputError saying what it is.  A FIFO or device is never read: the file is opened without
    blocking and checked with fstat on that very descriptor before a byte is read."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{what} file not found", file=path) from None
    except OSError as exc:
        raise InputError(f"{what} file cannot be read: {exc.strerror}", file=path) from None
    problem = _not_regular(st.st_mode, what, ext)
    if problem:
        raise InputError(problem, file=path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise InputError(f"{what} file cannot be read: {exc.strerror}", file=path) from None
    try:
        problem = _not_regular(os.fstat(fd).st_mode, what, ext)  # what was opened, should it have been swapped since
        if problem:
            raise InputError(problem, file=path)
        os.set_blocking(fd, True)
        fh = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with fh:
        yield fh


def _not_regular(mode: int, what: str = "FMU", ext: str = ".fmu") -> str | None:
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return f"is a directory, not an {ext} file"
    kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else
            "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "of an unknown kind")
    return f"is not a regular file ({kind}); an {what} is a {ext} file"


@contextmanager
def _unpacked(path: Path, fh: Any, max_unpacked_bytes: int, max_members: int) -> Iterator[OpenedFmu]:
    unzip_dir = Path(tempfile.mkdtemp(prefix="fishfmu-fmu-"))
    try:
        try:
            with zipfile.ZipFile(fh) as zf:
                check_members(path, zf, max_unpacked_bytes, max_members)
                _unpack(path, zf, unzip_dir, max_unpacked_bytes)
        except (zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError, EOFError, OSError,
                ValueError) as exc:  # what zipfile raises for damaged, encrypted or unsupported members
            raise InputError(f"corrupt or unreadable zip archive: {exc}", file=path) from exc
        md = _read_checked_description(path, unzip_dir)
        yield OpenedFmu(path, unzip_dir, md, variables_of(md))
    finally:
        shutil.rmtree(unzip_dir, ignore_errors=True)


def require_variables(fmu: OpenedFmu, wanted: dict[str, tuple[str, str]]) -> None:
    """Check that the FMU has each variable with the given (causality, type); name every problem.

    >>> from types import SimpleNamespace
    >>> fmu = SimpleNamespace(path="drive.fmu", variables={
    ...     "belt_speed": FmuVariable("belt_speed", "output", "Real", "continuous", 2, "m/s", None)})
    >>> require_variables(fmu, {"belt_sped": ("output", "Real")})
    Traceback (most recent call last):
    ...
    plant.errors.InputError: drive.fmu: no variable 'belt_sped' (did you mean 'belt_speed'?)
    """
    problems = []
    for name, (causality, type_) in wanted.items():
        var = fmu.variables.get(name)
        if var is None:
            hint = suggest(name, fmu.variables, template=" (did you mean '{}'?)")  # the problems are joined by "; "
            problems.append(f"no variable '{name}'{hint}")
            continue
        if var.causality != causality:
            problems.append(f"variable '{name}' has causality '{var.causality}', expected '{causality}'")
        if var.type != type_:
            problems.append(f"variable '{name}' is of type {var.type}, expected {type_}")
    if problems:
        raise InputError("; ".join(problems), file=fmu.path)
