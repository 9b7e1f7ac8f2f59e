"""The fixed parts of a line (``[[line.parts]]``): their triangles in the line frame, read from their STL files.

Read once per run (and by the replay, to draw them); the plant adds them to its contact as static triangles.
"""

from __future__ import annotations

import struct

import numpy as np
from stl import mesh as stl_mesh

from plant.contract.line import Line
from plant.errors import InputError


def part_triangles(line: Line) -> tuple[list[list[float]], list[list[int]]]:
    """The triangles of the line's fixed parts (``[[line.parts]]``) in the line frame, read from their STL files;
    InputError naming the part when a file cannot be read or a part lies outside the space the line's contact
    search covers (0.5 m before the line to 1 m after it, the guides' width + 0.1 m, 0.5 m below to 1 m above the
    belts)."""
    pts: list[list[float]] = []
    trigs: list[list[int]] = []
    z_lo, z_hi = line.z_range_m
    for i, part in enumerate(line.parts):
        where = f"line.parts[{i}].stl"
        try:
            vectors = stl_mesh.Mesh.from_file(part.stl).vectors.astype(float)
        except (OSError, ValueError, AssertionError, struct.error) as exc:
            raise InputError(f"cannot read part '{part.id}' as STL: {exc}", file=part.stl, where=where) from None
        if not len(vectors) or not np.all(np.isfinite(vectors)):
            raise InputError(f"part '{part.id}' has no triangles or a non-finite vertex", file=part.stl, where=where)
        v = vectors * part.scale + np.asarray(part.offset_m)
        lo, hi = v.reshape(-1, 3).min(axis=0), v.reshape(-1, 3).max(axis=0)
        if (lo[0] < line.x_start_m - 0.5 or hi[0] > line.x_end_m + 1.0 or max(-lo[1], hi[1]) > 0.5 * line.guide_width_m + 0.1
                or lo[2] < z_lo - 0.5 or hi[2] > z_hi + 1.0):
            raise InputError(f"part '{part.id}' spans x {lo[0]:.3f}..{hi[0]:.3f}, y {lo[1]:.3f}..{hi[1]:.3f}, z "
                             f"{lo[2]:.3f}..{hi[2]:.3f} m: outside the space over the line that contact covers "
                             "(see scale and offset_m)", file=part.stl, where=where)
        first = len(pts)
        pts += v.reshape(-1, 3).tolist()
        trigs += (first + np.arange(3 * len(v)).reshape(-1, 3)).tolist()
    return pts, trigs
