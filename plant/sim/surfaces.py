"""The line's fixed contact surfaces as triangles: each belt's top (in its own frame) and the side guides with the
infeed end plate (in the line frame).  Normals, (p1 - p0) x (p2 - p0), face where fish come from: GeneralContact
pushes spheres out along them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plant.contract.devices import CHUTE_DEPTH_M, DeviceShape, bin_walls, device_shapes, guide_openings, pusher_openings
from plant.contract.line import Line
from plant.contract.parts import part_triangles
from plant.fish.extensions import GuideWear

Triangles = tuple[list[list[float]], list[list[int]]]
"""(points, triangles as three point indices each)."""

DRUM_RADIUS_M = 0.03
"""A belt's rounded lip at each end (its drum)."""


def _quad(pts: list[list[float]], trigs: list[list[int]], a, b, c, d) -> None:
    """Two triangles a-b-c, a-c-d; the normal (b-a) x (c-a) must point towards the fish."""
    base = len(pts)
    pts += [list(a), list(b), list(c), list(d)]
    trigs += [[base, base + 1, base + 2], [base, base + 2, base + 3]]


def belt_surface(length_m: float, width_m: float) -> tuple[list[list[float]], list[list[int]]]:
    """Top surface of a belt in its own frame (origin at the upstream end of the top, z up),
    in 0.25 m strips, with a rounded lip (drum) at each end."""
    pts: list[list[float]] = []
    trigs: list[list[int]] = []
    hw = 0.5 * width_m
    xs = np.linspace(0.0, length_m, max(2, int(np.ceil(length_m / 0.25)) + 1))
    for x0, x1 in zip(xs[:-1], xs[1:]):
        _quad(pts, trigs, (x0, -hw, 0.0), (x1, -hw, 0.0), (x1, hw, 0.0), (x0, hw, 0.0))
    angles = np.radians([0.0, 30.0, 60.0, 90.0])
    r = DRUM_RADIUS_M
    for sign, x_end in ((1.0, length_m), (-1.0, 0.0)):
        for a0, a1 in zip(angles[:-1], angles[1:]):
            p0 = (x_end + sign * r * np.sin(a0), r * np.cos(a0) - r)
            p1 = (x_end + sign * r * np.sin(a1), r * np.cos(a1) - r)
            if sign > 0:
                _quad(pts, trigs, (p0[0], -hw, p0[1]), (p1[0], -hw, p1[1]), (p1[0], hw, p1[1]), (p0[0], hw, p0[1]))
            else:
                _quad(pts, trigs, (p1[0], -hw, p1[1]), (p0[0], -hw, p0[1]), (p0[0], hw, p0[1]), (p1[0], hw, p1[1]))
    return pts, trigs


def guide_walls(line: Line, guide_height_m: float, breaks: tuple[float, ...] = ()) -> tuple[list[list[float]],
                                                                                         list[list[int]]]:
    """Side walls along the whole line (straight, or along the guides' polylines), open where a pusher or diverter
    sends fish out, with a chute's end plates at a pusher's opening, and an end plate at the infeed; in panels of at
    most 0.5 m, none across an x of ``breaks`` (where guide sections of their own friction meet).  (A diverter's arm
    returns onto its opening's ends: a plate there would pinch a fish against it.)"""
    pts: list[list[float]] = []
    trigs: list[list[int]] = []
    z_lo = line.z_range_m[0] - 0.15
    z_hi = line.z_range_m[1] + guide_height_m
    x_lo, x_hi = line.x_start_m - 0.05, line.x_end_m
    corners = {x for g in ((line.guides.left, line.guides.right) if line.guides else ()) for x, _ in g}
    openings = guide_openings(line)  # where a pusher or diverter sends fish out, no wall
    corners |= {x for _, a, b in openings for x in (a, b)} | set(breaks)
    knots = sorted({x_lo, x_hi} | {x for x in corners if x_lo < x < x_hi})
    xs = np.concatenate([np.linspace(a, b, max(2, int(np.ceil((b - a) / 0.5)) + 1))[:-1]
                         for a, b in zip(knots[:-1], knots[1:])] + [[x_hi]])
    left, right = line.guide_y_at(xs)
    for x0, x1, l0, l1, r0, r1 in zip(xs[:-1], xs[1:], left[:-1], left[1:], right[:-1], right[1:]):
        open_on = {side for side, a, b in openings if a - 1e-9 <= 0.5 * (x0 + x1) <= b + 1e-9}
        if 1 not in open_on:  # left wall, normal inwards
            _quad(pts, trigs, (x0, l0, z_lo), (x1, l1, z_lo), (x1, l1, z_hi), (x0, l0, z_hi))
        if -1 not in open_on:  # right wall, normal inwards
            _quad(pts, trigs, (x0, r0, z_lo), (x0, r0, z_hi), (x1, r1, z_hi), (x1, r1, z_lo))
    for side, a, b in pusher_openings(line):  # its chute: a plate at each end, out from the guide line
        (ya, yb), out = (line.guide_y_at(np.array([a, b]))[0 if side > 0 else 1]), side * CHUTE_DEPTH_M
        if side > 0:  # normals into the chute: +x at its upstream end, -x at its downstream end
            _quad(pts, trigs, (a, ya, z_lo), (a, ya + out, z_lo), (a, ya + out, z_hi), (a, ya, z_hi))
            _quad(pts, trigs, (b, yb, z_lo), (b, yb, z_hi), (b, yb + out, z_hi), (b, yb + out, z_lo))
        else:
            _quad(pts, trigs, (a, ya, z_lo), (a, ya, z_hi), (a, ya + out, z_hi), (a, ya + out, z_lo))
            _quad(pts, trigs, (b, yb, z_lo), (b, yb + out, z_lo), (b, yb + out, z_hi), (b, yb, z_hi))
    xp = line.x_start_m - 0.02
    yl, yr = (float(v[0]) for v in line.guide_y_at([xp]))
    _quad(pts, trigs, (xp, yr, z_lo), (xp, yl, z_lo), (xp, yl, z_hi), (xp, yr, z_hi))  # end plate, normal +x
    return pts, trigs


@dataclass(frozen=True)
class LineSurfaces:
    """Every contact surface of a line, worked out once per run (STL files read once; each rebuild of the system
    adds these instead of recomputing them)."""

    guides: Triangles
    parts: Triangles
    """The fixed parts (``[[line.parts]]``), line frame."""
    bins: Triangles
    """The gates' bin walls, line frame."""
    belts: tuple[Triangles, ...]
    """Each conveyor's top, in its body's frame (along the slope of an inclined belt)."""
    devices: tuple[DeviceShape, ...]
    guide_sections: tuple[Triangles, ...] = ()
    """With guide sections of their own friction (``guide_wear``): the guides' triangles split by section (the
    infeed end plate and any chute plates in the section they stand in), in the order of the sections; else empty
    and ``guides`` holds them all."""


def split_by_x(tris: Triangles, edges: np.ndarray) -> tuple[Triangles, ...]:
    """Triangles split into the sections between ``edges`` by the x of their centroids (beyond the ends: the end
    sections), each section with the points it uses."""
    pts, trigs = np.asarray(tris[0], dtype=float), np.asarray(tris[1], dtype=np.int64)
    k = np.clip(np.searchsorted(edges, pts[trigs].mean(axis=1)[:, 0], side="right") - 1, 0, len(edges) - 2)
    out = []
    for s in range(len(edges) - 1):
        mine = trigs[k == s]
        used, local = np.unique(mine, return_inverse=True)
        out.append((pts[used].tolist(), local.reshape(-1, 3).tolist()))
    return tuple(out)


def line_surfaces(line: Line, guide_height_m: float, wear: GuideWear | None = None) -> LineSurfaces:
    """``wear`` on: the guides in sections of their own friction (else one)."""
    belts = tuple(belt_surface(c.length_m / np.cos(np.radians(c.incline_deg)), c.width_m) for c in line.conveyors)
    if wear is None or not wear.on:
        return LineSurfaces(guide_walls(line, guide_height_m), part_triangles(line), bin_walls(line), belts,
                            device_shapes(line))
    edges = wear.sections(line.x_start_m, line.x_end_m)[0]
    guides = guide_walls(line, guide_height_m, tuple(edges.tolist()))
    return LineSurfaces(guides, part_triangles(line), bin_walls(line), belts, device_shapes(line),
                        split_by_x(guides, edges))
