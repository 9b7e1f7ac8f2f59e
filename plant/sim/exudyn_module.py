"""Exudyn, imported once for the plant: its fast build (no range checks, about 30 % faster; the plant checks its
inputs itself), its start-up banner kept off the user's terminal, and a host that lacks a system library Exudyn loads
(even when nothing is drawn) reported as one line naming the library and the package that has it."""

from __future__ import annotations

import contextlib
import io
import re
import sys

from plant.errors import SystemDependencyError

EXUDYN_LIBRARY_PACKAGES = {
    # What Exudyn 1.13's compiled module loads from the system (readelf -d: libGL.so.1 and, through the
    # libglfw bundled in exudyn.libs, libX11.so.6; ldd: what those load), even when nothing is drawn,
    # with the Debian/Ubuntu package of each (dpkg -S).  libgl1 and libx11-6 pull in the rest.
    "libGL.so.1": "libgl1", "libX11.so.6": "libx11-6", "libGLX.so.0": "libglx0", "libGLdispatch.so.0": "libglvnd0",
    "libxcb.so.1": "libxcb1", "libXau.so.6": "libxau6", "libXdmcp.so.6": "libxdmcp6", "libbsd.so.0": "libbsd0",
    "libmd.so.0": "libmd0", "libstdc++.so.6": "libstdc++6", "libgcc_s.so.1": "libgcc-s1",
}
_MISSING_LIBRARY = re.compile(r"([^\s:/]+\.so(?:\.\d+)*): cannot open shared object file")
"""The dynamic loader's words for a library it cannot find (dlopen: "libGL.so.1: cannot open shared ...")."""


def exudyn_import_error(exc: ImportError) -> SystemDependencyError | None:
    """The one-line error for an ``import exudyn`` that failed because the system lacks a shared
    library (None when that is not why): names the library and the Debian/Ubuntu package that has it.

    >>> print(exudyn_import_error(ImportError("libGL.so.1: cannot open shared object file: No such file")))
    ... # doctest: +NORMALIZE_WHITESPACE
    this machine lacks libGL.so.1, which Exudyn (the plant's physics) loads even when nothing is drawn;
    install the Debian/Ubuntu package libgl1 (apt-get install libgl1)
    """
    missing = list(dict.fromkeys(_MISSING_LIBRARY.findall(str(exc))))
    if not missing:
        return None
    lacks = (f"this machine lacks {' and '.join(missing)}, which Exudyn (the plant's physics) loads even when "
             "nothing is drawn")
    packages = list(dict.fromkeys(EXUDYN_LIBRARY_PACKAGES.get(lib, "") for lib in missing))
    if "" in packages:
        return SystemDependencyError(f"{lacks}; install the system package that provides it (Debian/Ubuntu: "
                                     f"apt-file search {missing[0]})")
    names = " ".join(packages)
    return SystemDependencyError(f"{lacks}; install the Debian/Ubuntu package{'s' if len(packages) > 1 else ''} "
                                 f"{names} (apt-get install {names})")


if "exudyn" not in sys.modules:
    sys.exudynFast = True  # the build without range checks (~30 % faster); our inputs are checked here
try:
    with contextlib.redirect_stdout(io.StringIO()):  # it announces the fast build on stdout
        import exudyn as exu
except ImportError as exc:  # a bare host or container without the GL/X11 client libraries: not a bug of ours
    if (error := exudyn_import_error(exc)) is None:
        raise
    raise error from exc
exu.config.printToConsole = False  # no solver chatter (and no VelocityVerlet banner) on the user's terminal
