"""A salmon's five bodies: where they are cut, their masses and inertias, joints and contact spheres.

The paper's rag-doll has five rigid bodies (head, upper body, lower body, tail, tail fin) with
the mass split of Table II and the joint limits of Table III.  It gives no body lengths, so we
cut the fish where the mass split says: a salmon outline (height and width along the length,
``OUTLINE`` below) gives the mass per unit length (elliptic cross-section, uniform density),
and the four cuts are placed so that each body carries its Table II share.  The same outline,
scaled by the fish's own length, height and width, gives each body's centre of mass, inertia
tensor and contact spheres.

Body frame: origin at the body's centre of mass, x along the spine towards the head, y towards
the back (dorsal), z = x cross y (the fish's left side).  A fish lying on its side has its
local z vertical.

Contact shape: spheres of the local half-thickness (width/2) in one row along the spine where
the body is about as high as it is thick, and in two rows (towards the back and the belly)
where it is higher, so that seen from above a fish on its side is as long and as high as the
fish, and it is as thick as the fish.  Spheres of neighbouring bodies are kept far enough from
each joint that they do not touch when the joint is at its limits (GeneralContact has no
exclusion of bodies of the same fish).

>>> g = fish_geometry(length_m=0.68, height_m=0.18, width_m=0.08, mass_kg=3.698)
>>> [round(b.mass_kg, 3) for b in g.bodies]
[0.492, 1.277, 1.085, 0.622, 0.222]
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from plant.fish import fish_data
# Outline of an Atlantic salmon seen from the side (height) and from above (width), as fractions
# of the fish's maximum height and width, against the position along the length from the snout
# (0) to the tip of the tail fin (1).  Read off photographs of farmed salmon (an assumption: the
# paper gives only the totals).  The last entries are the tail fin: tall but thin and light.
OUTLINE_S = np.array([0.00, 0.05, 0.10, 0.20, 0.30, 0.40, 0.50, 0.60, 0.70, 0.78, 0.85, 0.88, 0.92, 0.96, 1.00])
OUTLINE_H = np.array([0.20, 0.50, 0.68, 0.88, 0.98, 1.00, 0.95, 0.82, 0.62, 0.42, 0.30, 0.30, 0.45, 0.65, 0.75])
OUTLINE_W = np.array([0.30, 0.60, 0.80, 0.95, 1.00, 1.00, 0.92, 0.78, 0.58, 0.40, 0.28, 0.25, 0.12, 0.08, 0.05])

MIN_SPHERE_RADIUS_M = 0.012
"""No contact sphere of a fish is smaller (its tail fin's): what a moving device must not pass in one integration step."""
BODY_NAMES = ("head", "upper_body", "lower_body", "tail", "tail_fin")
N_BODIES = 5
"""The paper's rag-doll; the cuts, sphere layout and joint clearances are always worked out for it."""
FISH_MODELS = {"paper5": 5, "joined4": 4}
"""The fish models a scenario can choose (``plant.fish_model``) and their bodies per fish: the paper's five, or
four with the tail fin joined rigidly to the tail (see :func:`fish_geometry`)."""
_GRID = np.linspace(0.0, 1.0, 801)


@dataclass(frozen=True)
class BodyGeometry:
    """One rigid body of the fish, in its own frame (origin at its centre of mass)."""

    name: str
    s_start: float
    """Cut nearer the snout, as a fraction of length from the snout."""
    s_end: float
    """Cut nearer the tail, as a fraction of length from the snout."""
    mass_kg: float
    inertia_kgm2: tuple[float, float, float]
    """Principal moments about local x (spine), y (dorsal axis) and z (lateral axis)."""
    com_from_snout_m: float
    """Distance of the centre of mass from the snout, along the spine."""
    spheres: tuple[tuple[float, float, float], ...]
    """Contact spheres as (local x, local y, radius) in metres; local z is 0."""
    outline: tuple[tuple[float, float, float], ...] = ()
    """The body's true shape for sensors: cross-sections every centimetre as (local x, half-height,
    half-thickness); each is a stadium (a capsule along local y), unlike the coarser contact spheres."""


@dataclass(frozen=True)
class FishGeometry:
    """The five bodies of one fish and the joints between them (on the spine at each cut)."""

    length_m: float
    height_m: float
    width_m: float
    mass_kg: float
    bodies: tuple[BodyGeometry, ...]
    joint_from_snout_m: tuple[float, ...] = field(default=())

    @property
    def mid_from_snout_m(self) -> float:
        """The tracked position of a fish is its mid-length point (contracts/measured-data.md)."""
        return 0.5 * self.length_m

    def spine_point(self, s: float) -> tuple[int, np.ndarray]:
        """(body index, position in that body's frame) of the spine point at fraction s of the length from the snout
        (the tracked points; the poses themselves: :meth:`plant.sim.state.PlantState.fish_poses`)."""
        d = s * self.length_m
        for i, b in enumerate(self.bodies):
            if b.s_start <= s <= b.s_end or i == len(self.bodies) - 1:
                return i, np.array([b.com_from_snout_m - d, 0.0, 0.0])
        raise AssertionError("unreachable")


def _area(s: np.ndarray) -> np.ndarray:
    """Cross-section area per unit (height x width), elliptic: pi/4 h w."""
    return np.pi / 4 * np.interp(s, OUTLINE_S, OUTLINE_H) * np.interp(s, OUTLINE_S, OUTLINE_W)


@functools.cache
def cut_positions(mass_fractions: tuple[float, ...] | None = None) -> tuple[float, ...]:
    """The four cuts (fractions of length from the snout) that give each body its mass share."""
    if mass_fractions is None:
        mass_fractions = tuple(fish_data.table2()["fraction"].to_numpy() / fish_data.table2()["fraction"].sum())
    a = _area(_GRID)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * np.diff(_GRID))])
    cum /= cum[-1]
    targets = np.cumsum(mass_fractions)[:-1]
    return tuple(float(np.interp(t, cum, _GRID)) for t in targets)


def _body_mass_properties(s0: float, s1: float, length_m: float, height_m: float, width_m: float,
                          mass_kg: float) -> tuple[float, tuple[float, float, float]]:
    """Centre of mass (from snout) and principal inertias of the slice [s0, s1] carrying mass_kg."""
    s = np.linspace(s0, s1, 121)
    x = s * length_m
    a = np.interp(s, OUTLINE_S, OUTLINE_H) * height_m / 2  # semi-axis towards the back
    b = np.interp(s, OUTLINE_S, OUTLINE_W) * width_m / 2   # semi-axis towards the side
    dm = np.pi * a * b
    dm = dm / np.trapezoid(dm, x) * mass_kg
    xc = float(np.trapezoid(dm * x, x) / mass_kg)
    ixx = np.trapezoid(dm * (a**2 + b**2) / 4, x)
    iyy = np.trapezoid(dm * (b**2 / 4 + (x - xc) ** 2), x)  # about the dorsal axis: thickness + length
    izz = np.trapezoid(dm * (a**2 / 4 + (x - xc) ** 2), x)  # about the lateral axis: height + length
    return xc, (float(ixx), float(iyy), float(izz))


def _sphere_radii(s: np.ndarray, width_m: float, min_radius_m: float) -> list[float]:
    """The spheres' radius at each position ``s`` along the fish: its half-thickness there, at least
    ``min_radius_m``."""
    return np.maximum(0.5 * width_m * np.interp(s, OUTLINE_S, OUTLINE_W), min_radius_m).tolist()


def _sphere_rows(s: np.ndarray, length_m: float, height_m: float, width_m: float,
                 min_radius_m: float) -> list[list[tuple[float, float]]]:
    """(local y offset, radius) of the spheres across the body at each position of ``s`` (one interpolation for a
    body's every position: one call per position cost most of a fish's geometry)."""
    r = _sphere_radii(s, width_m, min_radius_m)
    half_h = (0.5 * height_m * np.interp(s, OUTLINE_S, OUTLINE_H)).tolist()
    return [[(0.0, ri)] if hi - ri < 0.5 * ri else [(hi - ri, ri), (-(hi - ri), ri)] for ri, hi in zip(r, half_h)]


def _spheres_overlap_at_limits(pa: np.ndarray, ra: np.ndarray, pb: np.ndarray, rb: np.ndarray,
                               limits_rad: tuple[float, float]) -> bool:
    """True if a sphere of body a (positions relative to the joint) touches one of body b
    when b is bent to any corner of the joint's limits (lateral about y, dorso-ventral about z)."""
    q = pb @ _limit_corners(*limits_rad)  # b's spheres at all nine corners at once: (9, nb, 3)
    d = np.linalg.norm(pa[None, :, None, :] - q[:, None, :, :], axis=3)
    return bool(np.any(d < (ra[:, None] + rb[None, :])))


@functools.lru_cache(maxsize=64)
def _limit_corners(lat: float, dv: float) -> np.ndarray:
    """The transposed rotations of a joint bent to each corner of its limits (lateral about y, dorso-ventral about
    z), stacked (9, 3, 3): the same for every fish cut alike, worked out once (they were most of a fish's geometry's
    time)."""
    corners = []
    for ay in (-lat, 0.0, lat):
        for az in (-dv, 0.0, dv):
            cy, sy, cz, sz = np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
            rot = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]) @ np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
            corners.append(rot.T)
    out = np.array(corners)
    out.setflags(write=False)  # shared by every fish
    return out


def _body_spheres(i: int, cuts: tuple[float, ...], clear_head: float, clear_tail: float, length_m: float,
                  height_m: float, width_m: float, min_radius_m: float, spacing: float) -> list[tuple[float, float, float]]:
    """Body i's spheres as (distance from snout, local y, radius), evenly spaced along the spine, kept
    ``clear_head`` / ``clear_tail`` radii from the joints at its ends (``min_radius_m`` already the fish's floor)."""
    x0, x1 = cuts[i] * length_m, cuts[i + 1] * length_m

    def radius_at(x: np.ndarray) -> list[float]:
        return _sphere_radii(x / length_m, width_m, min_radius_m)

    # first/last centre: one radius inside the snout / fin tip, or clear of the joint
    r_head, r_head_in, r_tail_in, r_tail = radius_at(np.array([x0 - 1e-6, x0 + 1e-6, x1 - 1e-6, x1 + 1e-6]))
    lo = radius_at(np.array([x0]))[0] if i == 0 else x0 + clear_head * max(r_head, r_head_in)
    hi = x1 - radius_at(np.array([x1]))[0] if i == N_BODIES - 1 else x1 - clear_tail * max(r_tail_in, r_tail)
    if i == N_BODIES - 1:
        # the fin: one pair of spheres at its tip, so that contact and photo-eyes see the whole
        # length (the fin is light; more spheres would only cost time)
        xs = np.array([max(hi, 0.5 * (x0 + x1))])
    elif hi <= lo:
        xs = np.array([0.5 * (x0 + x1)])
    else:
        # narrow parts (tail, fin) would need many small spheres: space them by at least
        # a third of the fish's thickness, which keeps the count near 30 per fish
        pitch = spacing * max(radius_at(np.array([0.5 * (lo + hi)]))[0], width_m / 3)
        n = int(np.ceil((hi - lo) / pitch)) + 1
        xs = np.linspace(lo, hi, n)
    rows = _sphere_rows(xs / length_m, length_m, height_m, width_m, min_radius_m)
    return [(x, y, r) for x, row in zip(xs.tolist(), rows) for (y, r) in row]


def _place_spheres(cuts: tuple[float, ...], clearance: list[float], length_m: float, height_m: float,
                   width_m: float, min_radius_m: float, spacing: float, min_radius_fraction: float,
                   placed: dict | None = None) -> list[list[tuple[float, float, float]]]:
    """Per body, spheres as (distance from snout, local y, radius), evenly spaced along the spine.  ``placed``: the
    bodies placed before, by their two clearances (the clearance search moves one joint's at a time)."""
    placed = {} if placed is None else placed
    min_radius_m = max(min_radius_m, min_radius_fraction * width_m)
    raw = []
    for i in range(N_BODIES):
        key = (i, clearance[i - 1] if i > 0 else 0.0, clearance[i] if i < N_BODIES - 1 else 0.0)
        if key not in placed:
            placed[key] = _body_spheres(i, cuts, key[1], key[2], length_m, height_m, width_m, min_radius_m, spacing)
        raw.append(placed[key])
    return raw


def _touch_at_limits(a_side: list[tuple[float, float, float]], b_side: list[tuple[float, float, float]],
                     x_joint_m: float, limits_rad: tuple[float, float]) -> bool:
    pa = np.array([[x_joint_m - x, y, 0.0] for x, y, _ in a_side])  # local x towards the head
    pb = np.array([[x_joint_m - x, y, 0.0] for x, y, _ in b_side])
    ra = np.array([r for *_, r in a_side])
    rb = np.array([r for *_, r in b_side])
    return _spheres_overlap_at_limits(pa, ra, pb, rb, limits_rad)


def _with_min_fraction(fractions: np.ndarray, minimum: float) -> np.ndarray:
    """Raise bodies lighter than ``minimum`` to it, taking the mass from their neighbour towards the head."""
    out = fractions.copy()
    for i in range(len(out) - 1, 0, -1):
        if out[i] < minimum:
            out[i - 1] -= minimum - out[i]
            out[i] = minimum
    return out


def fish_geometry(length_m: float, height_m: float, width_m: float, mass_kg: float,
                  joint_limits_rad: tuple[tuple[float, float], ...] | None = None,
                  sphere_spacing: float = 1.5, min_radius_m: float = MIN_SPHERE_RADIUS_M,
                  min_body_fraction: float = 0.06, min_radius_fraction: float = 0.3,
                  fin_joined: bool = False) -> FishGeometry:
    """Cut a fish of the given size into five bodies with masses, inertias and contact spheres.

    ``joint_limits_rad``: per joint (lateral, dorso-ventral) bending limits; spheres near each
    joint are moved away from it until the neighbouring bodies' spheres do not touch at these
    limits (+15 %).  ``sphere_spacing``: distance between spheres along the spine in radii.
    ``min_radius_fraction``: no sphere is thinner than this fraction of the fish's thickness: the
    snout and the fin are thinner, but a linear penalty contact stops a sphere only within its
    radius, and these are the parts that other fish land on.
    ``min_body_fraction``: numerical mass scaling, see ``plant.sim.params.NumericsParams``; the paper's
    2.2 % tail fin is raised to it with mass taken from the tail body (total mass unchanged).
    ``fin_joined``: four bodies, the tail fin part of the tail (model ``joined4``): the tail body runs from the
    third cut to the fin's tip and carries the paper's tail and fin shares together (Table II, 22.8 % for sample
    #16) with its own centre of mass and inertia from the outline; no mass floor (the fin is no body of its own);
    the same contact spheres as the five-body fish; joints 1-3 of Table III.
    """
    if joint_limits_rad is None:
        t3 = fish_data.table3()
        joint_limits_rad = tuple((float(np.radians(a)), float(np.radians(b)))
                                 for a, b in zip(t3["swing1_deg"], t3["swing2_deg"]))
    fractions = fish_data.table2()["fraction"].to_numpy()
    fractions = fractions / fractions.sum()
    cuts = (0.0, *cut_positions(), 1.0)
    if not fin_joined:
        fractions = _with_min_fraction(fractions, min_body_fraction)

    # Clearance of the spheres from each joint, in radii of the larger neighbouring sphere,
    # grown until the two bodies' spheres do not touch with the joint at its limits (+15 %).
    clearance = [1.0] * (N_BODIES - 1)
    placed: dict = {}
    tested: dict = {}  # a joint's test by its two bodies' clearances: most do not move from one round to the next
    for _ in range(40):
        raw = _place_spheres(cuts, clearance, length_m, height_m, width_m, min_radius_m, sphere_spacing,
                             min_radius_fraction, placed)
        touching = []
        for j in range(N_BODIES - 1):
            key = (j, *clearance[max(j - 1, 0):j + 2])
            if key not in tested:
                tested[key] = _touch_at_limits(raw[j], raw[j + 1], cuts[j + 1] * length_m,
                                               tuple(1.15 * a for a in joint_limits_rad[j]))
            if tested[key]:
                touching.append(j)
        if not touching:
            break
        for j in touching:
            clearance[j] *= 1.05
    else:
        raise ValueError("cannot place contact spheres clear of the joints at their limits")

    if fin_joined:  # the tail and its fin one body: its spheres both's, its share both's
        raw = [*raw[:3], raw[3] + raw[4]]
        fractions = np.array([*fractions[:3], fractions[3] + fractions[4]])
        cuts = (*cuts[:4], 1.0)
    bodies = []
    for i in range(len(raw)):
        s0, s1 = cuts[i], cuts[i + 1]
        m = mass_kg * float(fractions[i])
        xc, inertia = _body_mass_properties(s0, s1, length_m, height_m, width_m, m)
        # local x points to the head: a point at distance d from the snout is at local x = xc - d
        spheres = tuple((xc - x, y, r) for x, y, r in raw[i])
        stations = np.linspace(s0, s1, max(2, int(np.ceil((s1 - s0) * length_m / 0.01)) + 1))
        outline = tuple(zip((xc - stations * length_m).tolist(),
                            (0.5 * height_m * np.interp(stations, OUTLINE_S, OUTLINE_H)).tolist(),
                            (0.5 * width_m * np.interp(stations, OUTLINE_S, OUTLINE_W)).tolist()))
        bodies.append(BodyGeometry(BODY_NAMES[i], s0, s1, m, inertia, xc, spheres, outline))
    return FishGeometry(length_m, height_m, width_m, mass_kg, tuple(bodies),
                        tuple(c * length_m for c in cuts[1:-1]))
