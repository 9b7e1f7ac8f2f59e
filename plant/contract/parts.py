"""The fixed parts of a line (``[[line.parts]]``): their triangles in the line frame, read from their STL files.

Read by every command that checks a line before it writes anything (``check``, ``run``, ``export-fmu``, ...), again
when a run builds its plant, and by the replay to draw them; the plant adds them to its contact as static triangles.

Limits (checked before anything is allocated for the triangles): a part's file must be a regular file (a FIFO would
block the reader forever, a device never ends) of at most :data:`MAX_STL_BYTES`, a binary STL must hold the
triangles its header claims, and the line's parts together at most :data:`MAX_PART_TRIANGLES` triangles.
"""

from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np
from stl import Mode
from stl import mesh as stl_mesh

from plant.contract.line import Line, Part
from plant.errors import InputError
from plant.validation import read_regular_file

MAX_PART_TRIANGLES = 100_000
"""Triangles of all of a line's parts together.  A chute or deflector plate exported from CAD at a fine tolerance has
a few hundred to some 20 000 triangles (a bent sheet with rounded edges); 100 000 leaves five times that.  Measured
(a 1 x 0.4 m plate cut into triangles, one fish resting on it, 100 plant steps on a 2-core x86_64): 1 922 triangles
build in 0.06 s and step 1.8 ms; 99 458 build in 1.4 s, step 16 ms and take 180 MB more.  Ten million (a scanned
part) would take gigabytes and make every step search them."""
BINARY_HEADER_BYTES, BINARY_TRIANGLE_BYTES = 84, 50
"""A binary STL: an 80-byte header and a 4-byte triangle count, then 50 bytes per triangle."""
MAX_STL_BYTES = 64 * 1024 * 1024
"""One STL file: an ASCII file of :data:`MAX_PART_TRIANGLES` triangles takes about 25 MB (some 250 bytes a facet,
more with deep indentation); the binary one 5 MB."""


def read_stl_bytes(path: str | Path, where: str) -> bytes:
    """The bytes of the STL file at ``path``: InputError naming ``where`` when it is missing, not a regular file (a
    FIFO is refused, never waited on) or larger than :data:`MAX_STL_BYTES`."""
    return read_regular_file(path, MAX_STL_BYTES, "STL file", where, missing="STL file not found")


def stl_vectors(data: bytes, path: str | Path, where: str, max_triangles: int) -> np.ndarray:
    """The triangles (n x 3 x 3, STL units) of an STL file's ``data``, ASCII or binary; InputError naming ``where``
    when it is not an STL, a binary one claims more triangles than it holds, or it has more than ``max_triangles``.
    A binary file is known by its size (its header may begin with "solid" too, as SolidWorks writes it)."""
    if not data.strip():
        raise InputError("is empty: no triangles", file=path, where=where)
    binary_count = (struct.unpack("<I", data[80:84])[0] if len(data) >= BINARY_HEADER_BYTES else None)
    is_binary = binary_count is not None and (
        len(data) == BINARY_HEADER_BYTES + BINARY_TRIANGLE_BYTES * binary_count
        or not data[:80].lstrip().lower().startswith(b"solid"))
    if is_binary:
        held = (len(data) - BINARY_HEADER_BYTES) // BINARY_TRIANGLE_BYTES
        if binary_count > held:
            raise InputError(f"a binary STL whose header claims {binary_count} triangles but the file holds "
                             f"{held}: cut short, or not an STL file", file=path, where=where)
        if binary_count > max_triangles:
            raise InputError(f"has {binary_count} triangles; the line's parts may have at most "
                             f"{MAX_PART_TRIANGLES} together", file=path, where=where)
    try:
        vectors = stl_mesh.Mesh.from_file(str(path), fh=io.BytesIO(data), calculate_normals=False,
                                          mode=Mode.BINARY if is_binary else Mode.ASCII).vectors
    except (OSError, ValueError, AssertionError, struct.error, RuntimeError, TypeError) as exc:
        raise InputError(f"cannot read as STL: {exc}", file=path, where=where) from None
    if len(vectors) > max_triangles:
        raise InputError(f"has {len(vectors)} triangles; the line's parts may have at most {MAX_PART_TRIANGLES} "
                         "together", file=path, where=where)
    return vectors.astype(float)


def part_triangles(line: Line) -> tuple[list[list[float]], list[list[int]]]:
    """The triangles of the line's fixed parts (``[[line.parts]]``) in the line frame, read from their STL files;
    InputError naming the part's ``line.parts[i].stl`` when a file cannot be read (see the module's limits) or a part
    lies outside the space the line's contact search covers (0.5 m before the line to 1 m after it, the guides' width
    + 0.1 m, 0.5 m below to 1 m above the belts)."""
    pts: list[list[float]] = []
    trigs: list[list[int]] = []
    budget = MAX_PART_TRIANGLES
    for i, part in enumerate(line.parts):
        v = _placed(line, part, f"line.parts[{i}].stl", budget)
        budget -= len(v)
        first = len(pts)
        pts += v.reshape(-1, 3).tolist()
        trigs += (first + np.arange(3 * len(v)).reshape(-1, 3)).tolist()
    return pts, trigs


def _placed(line: Line, part: Part, where: str, max_triangles: int) -> np.ndarray:
    """One part's triangles in the line frame, checked."""
    try:
        vectors = stl_vectors(read_stl_bytes(part.stl, where), part.stl, where, max_triangles)
    except InputError as exc:
        raise InputError(f"part '{part.id}': {exc.message}", exc.file, exc.where) from None
    if not len(vectors) or not np.all(np.isfinite(vectors)):
        raise InputError(f"part '{part.id}' has no triangles or a non-finite vertex", file=part.stl, where=where)
    v = vectors * part.scale + np.asarray(part.offset_m)
    if not np.all(np.isfinite(v)):  # finite STL units times a finite scale can still overflow
        raise InputError(f"part '{part.id}' has a vertex beyond the range of a float once scaled", file=part.stl,
                         where=where)
    lo, hi = v.reshape(-1, 3).min(axis=0), v.reshape(-1, 3).max(axis=0)
    z_lo, z_hi = line.z_range_m
    if (lo[0] < line.x_start_m - 0.5 or hi[0] > line.x_end_m + 1.0 or max(-lo[1], hi[1]) > 0.5 * line.guide_width_m + 0.1
            or lo[2] < z_lo - 0.5 or hi[2] > z_hi + 1.0):
        raise InputError(f"part '{part.id}' spans x {lo[0]:.3f}..{hi[0]:.3f}, y {lo[1]:.3f}..{hi[1]:.3f}, z "
                         f"{lo[2]:.3f}..{hi[2]:.3f} m: outside the space over the line that contact covers "
                         "(see scale and offset_m)", file=part.stl, where=where)
    return v
