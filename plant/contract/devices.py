"""The actuated devices of a line (``[[line.devices]]``): their shape, how they move, where a fish they take off goes.

One description for the plant (which puts each device's triangles on a body it moves), the health checks (which let
a fish leave where a device sends it) and the replay (which draws them).  A device's state is its position ``p``
along its travel, 0 at home to 1 at the end of it.

- **gate**: a short belt section (a flap whose surface runs at the speed of the belt before it: a dead plate as long
  as a gate would stall a fish on it), hinged at its upstream edge ``x_m`` 5 mm below the end of the belt before it,
  spanning the lane; open, it turns about the hinge (axis y) so that its far edge swings down by
  ``p * travel_deg``.  Under the gap, the walls of its bin: fixed plates below the end of the belt before it and
  the start of the belt after it, down to 0.8 m below the hinge, so that a falling fish goes down into the bin and
  not under either belt.  A fish whose mid-length point is 0.15 m below the hinge in the gate's zone has gone
  through: rejected.
- **pusher**: a paddle (``length_m`` along x, 0.15 m high, 3 cm thick) whose face sits on the guide opposite
  ``side`` at home and moves ``p * travel_m`` across towards ``side``; the guide on ``side`` is open over the
  paddle's length and 0.15 m beyond each end of it.  A shield (a plate at the paddle's upstream end, as long as the stroke, behind the home guide
  when home) closes the lane behind the paddle while it is out: the fish that come meanwhile wait at it.
- **diverter**: an arm (``length_m``, 0.15 m high, 2 cm thick) that is the guide on ``side`` over
  ``x_m .. x_m + length_m`` at home, pivoting about a vertical axis at its downstream end; its free end swings
  ``p * travel_deg`` into the lane, and the guide it was is open.

A pusher's or diverter's fish whose mid-length point is 0.05 m beyond the guide line on ``side`` has left: rejected.

>>> from plant.contract.line import Line
>>> line = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
...     {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0},
...     {"id": "c2", "x_start_m": 2.4, "length_m": 1.0, "width_m": 0.5, "z_top_m": -0.02}],
...     "devices": [{"id": "g", "kind": "gate", "x_m": 2.0, "length_m": 0.35},
...                 {"id": "p", "kind": "pusher", "x_m": 0.5, "length_m": 0.8}]})
>>> gate, pusher = device_shapes(line)
>>> [round(float(v), 3) for v in gate.pose(1.0)[1]], round(float(gate.travel), 4)   # open: 60 deg about y
([0.0, 1.047, 0.0], 1.0472)
>>> [round(float(v), 3) for v in pusher.pose(0.5)[0]], pusher.opening  # half way across, to the right
([0.5, 0.0, 0.0], (-1, 0.35, 1.45))
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plant.contract.line import Device, Line
from plant.fish.fish_body import MIN_SPHERE_RADIUS_M

PADDLE_HEIGHT_M = 0.15
"""Height of a pusher's paddle and a diverter's arm above the belt: above any fish lying on it, below the guides."""
CLEARANCE_M = 0.003
"""A paddle's or arm's lower edge above the belt (triangles do not touch triangles, but a fish's fin could be
caught between them)."""
GATE_DROP_M = 0.15
"""A fish whose mid-length point is this far below a gate's hinge, over its flap, has gone through."""
SIDE_CLEAR_M = 0.05
"""A fish whose mid-length point is this far beyond the guide line at a pusher's or diverter's opening has left: about
half a fish's thickness, its middle off the lane (off the belt where the belt ends at the guide; where the belt is wider
than the lane, a funnel's, it would ride on outside the guide)."""
SHIELD_THICKNESS_M = 0.02
"""A pusher's shield: the plate at the paddle's upstream end that closes the lane behind the paddle while it is out."""
OPENING_MARGIN_M = 0.15
"""A pusher's opening reaches this far beyond each end of its paddle: a fish lying across an end of the paddle, pushed
at one end, turns out through the opening instead of being pinched between the paddle and the end of the guide (the
paddle is position-controlled: nothing limits its force)."""
CHUTE_DEPTH_M = 0.5
"""How far out from the guide line the plates at the ends of a pusher's opening reach (its chute): a fish going out
stays between them (one half out, carried on by the belt, cannot slide past the end of the guide outside it)."""
ZONE_MARGIN_M = 0.1
"""Along x, a device's exit zone reaches this far beyond its flap, paddle or arm..."""
SIDE_REACH_M = 0.6
"""... and this far downstream of it: a fish leaves moving downstream (a diverter's past the arm's pivot, a gate's
head first under the next belt's end as it falls into the bin)."""


@dataclass(frozen=True)
class DeviceShape:
    """One device of a line: its triangles in its body's frame and how that body moves with the position ``p``."""

    device: Device
    origin_m: np.ndarray
    """(3,) the body's origin at home, line frame: a gate's hinge, a pusher's paddle face, a diverter's pivot."""
    points_m: np.ndarray
    """(n, 3) triangle corners in the body's frame (its axes those of the line at home)."""
    triangles: np.ndarray
    """(m, 3) corner indices; the normal (p1 - p0) x (p2 - p0) faces where fish come from."""
    travel: float
    """Full travel: rad for a gate or diverter, m for a pusher."""
    axis: np.ndarray
    """(3,) unit axis of the motion: of the rotation (gate, diverter) or of the translation (pusher)."""
    opening: tuple[int, float, float] | None
    """(side: +1 left / -1 right, x from, x to) of the guide a pusher or diverter opens; None for a gate."""
    hinge_z_m: float = 0.0
    feeder: int = -1
    """A gate: the index of the conveyor before it, whose speed its surface runs at; -1 for the others."""
    feeder_end_m: float = 0.0
    """A gate: where the belt before it ends."""

    @property
    def gap_from_m(self) -> float:
        """Where a gate's gap starts: the end of the belt before it (its hinge may sit a little after it)."""
        return min(self.device.x_m, self.feeder_end_m) if self.feeder >= 0 else self.device.x_m

    @property
    def fastest_mps(self) -> float:
        """Speed of the device's fastest point while it moves: a pusher's paddle, the far edge of a gate's flap or of a
        diverter's arm."""
        reach_m = 1.0 if self.device.kind == "pusher" else self.device.length_m
        return reach_m * self.travel / self.device.stroke_s

    @property
    def rotates(self) -> bool:
        return self.device.kind != "pusher"

    def pose(self, p: float) -> tuple[np.ndarray, np.ndarray]:
        """(position of the body's origin (3,), rotation vector (3,)) at position ``p`` (0 home, 1 end)."""
        if self.rotates:
            return self.origin_m.copy(), self.axis * (p * self.travel)
        return self.origin_m + self.axis * (p * self.travel), np.zeros(3)

    def velocity(self, p: float, p_per_s: float, surface_mps: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(velocity of the body (3,), angular velocity (3,); the same in the body's frame: about a fixed axis)
        at ``p`` while it changes at ``p_per_s``; a gate's surface running at ``surface_mps`` along the flap."""
        if self.device.kind == "gate":
            a = p * self.travel
            return surface_mps * np.array([np.cos(a), 0.0, -np.sin(a)]), self.axis * (p_per_s * self.travel)
        if self.rotates:
            return np.zeros(3), self.axis * (p_per_s * self.travel)
        return self.axis * (p_per_s * self.travel), np.zeros(3)

    def exit_zone(self, x_m: np.ndarray, y_m: np.ndarray, z_m: np.ndarray, line: Line) -> np.ndarray:
        """True where a fish's mid-length point at (x, y, z) has left the line through this device."""
        if self.device.kind == "gate":
            return self.region(x_m, y_m, line) & (z_m < self.hinge_z_m - GATE_DROP_M)
        return self.region(x_m, y_m, line, beyond_m=SIDE_CLEAR_M)

    def along(self, x_m: np.ndarray) -> np.ndarray:
        """True where x is along the stretch where this device takes fish off: its flap, or its guide opening, with
        :data:`ZONE_MARGIN_M` upstream and :data:`SIDE_REACH_M` downstream."""
        x_from, x_to = (self.opening[1], self.opening[2]) if self.opening else (self.gap_from_m, self.device.x_end_m)
        return (x_m >= x_from - ZONE_MARGIN_M) & (x_m <= x_to + SIDE_REACH_M)

    def region(self, x_m: np.ndarray, y_m: np.ndarray | None, line: Line, beyond_m: float = 0.0) -> np.ndarray:
        """True where (x, y) is where a fish leaving through this device goes: over a gate's gap; beyond the guide
        line (by more than ``beyond_m``) at a pusher's or diverter's opening (anywhere across with ``y_m`` None: a
        fish falling off a belt's side can swing under it)."""
        along = self.along(x_m)
        if self.device.kind == "gate":
            return along
        if y_m is None:
            return along
        side = self.opening[0]
        guide = line.guide_y_at(x_m)[0 if side > 0 else 1]
        return along & (side * (y_m - guide) > beyond_m)


def _box(pts: list, trigs: list, x: tuple[float, float], y: tuple[float, float], z: tuple[float, float],
         bottom: bool = False) -> None:
    """The faces of an axis-aligned box, normals outwards; the bottom only with ``bottom`` (a gate's flap closing
    onto a fish in its gap must push it down: a triangle acts on a sphere from its front side only)."""
    (x0, x1), (y0, y1), (z0, z1) = x, y, z
    faces = (((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)),   # -y
             ((x0, y1, z0), (x0, y1, z1), (x1, y1, z1), (x1, y1, z0)),   # +y
             ((x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)),   # -x
             ((x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)),   # +x
             ((x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)))   # +z
    if bottom:
        faces += (((x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0)),)  # -z
    for a, b, c, e in faces:
        base = len(pts)
        pts += [a, b, c, e]
        trigs += [[base, base + 1, base + 2], [base, base + 2, base + 3]]


def device_shape(line: Line, d: Device) -> DeviceShape:
    """The shape and motion of device ``d`` of ``line``."""
    pts: list = []
    trigs: list = []
    left, right = (float(v) for v in line.guide_y_at(np.array(0.5 * (d.x_m + d.x_end_m))))
    if d.kind == "gate":
        # the belt before the gap, which ends at the hinge or before it (not the next one, which ends after it)
        feeder = max(k for k, c in enumerate(line.conveyors) if c.x_end_m <= d.x_m + 1e-6)
        hinge_z = line.conveyors[feeder].z_end_m - 0.005
        # the flap: its top at the hinge's height, spanning the lane and a little under the guides
        _box(pts, trigs, (0.0, d.length_m), (right - 0.02, left + 0.02), (-0.02, 0.0), bottom=True)
        return DeviceShape(d, np.array([d.x_m, 0.0, hinge_z]), np.array(pts, float), np.array(trigs),
                           np.radians(d.travel_deg or 60.0), np.array([0.0, 1.0, 0.0]), None, hinge_z, feeder,
                           line.conveyors[feeder].x_end_m)
    side = 1 if d.side == "left" else -1
    z_belt = min(line.z_top_at(d.x_m), line.z_top_at(d.x_end_m))
    z = (CLEARANCE_M, PADDLE_HEIGHT_M)
    if d.kind == "pusher":
        home_y = right if side > 0 else left  # the paddle's face on the guide opposite the side fish leave by
        travel = d.travel_m if d.travel_m is not None else left - right
        # the paddle behind its face (away from the lane)
        _box(pts, trigs, (0.0, d.length_m), (-0.03, 0.0) if side > 0 else (0.0, 0.03), z)
        # its shield: a plate at its upstream end reaching back a whole stroke (through a slot in the guide it
        # retracts behind), so that fish the belt brings while the paddle is out wait upstream of it instead of
        # running in behind it, where the returning paddle would press them into its home guide
        back = SHIELD_THICKNESS_M + 0.03 + travel
        _box(pts, trigs, (0.0, SHIELD_THICKNESS_M), (-back, 0.0) if side > 0 else (0.0, back), z)
        return DeviceShape(d, np.array([d.x_m, home_y, z_belt]), np.array(pts, float), np.array(trigs), travel,
                           np.array([0.0, float(side), 0.0]),
                           (side, max(d.x_m - OPENING_MARGIN_M, line.x_start_m), min(d.x_end_m + OPENING_MARGIN_M,
                                                                                       line.x_end_m)))
    guide_y = float(line.guide_y_at(np.array(d.x_end_m))[0 if side > 0 else 1])
    # the arm upstream of its pivot, its inner face on the guide line
    _box(pts, trigs, (-d.length_m, 0.0), (0.0, 0.02) if side > 0 else (-0.02, 0.0), z)
    # its free end swings into the lane: about +z for a left arm (towards -y), about -z for a right one
    return DeviceShape(d, np.array([d.x_end_m, guide_y, z_belt]), np.array(pts, float), np.array(trigs),
                       np.radians(d.travel_deg or 45.0), np.array([0.0, 0.0, float(side)]), (side, d.x_m, d.x_end_m))


def device_shapes(line: Line) -> tuple[DeviceShape, ...]:
    """Every device of ``line``, in its order."""
    return tuple(device_shape(line, d) for d in line.devices)


BIN_DEPTH_M = 0.8
"""How far below a gate's hinge the walls of its bin reach."""


def bin_walls(line: Line) -> tuple[list[list[float]], list[list[int]]]:
    """Static triangles (line frame) of every gate's bin: a plate facing downstream under the end of the belt before
    the gap (from just below its drum) and one facing upstream under the start of the belt after it, across the lane."""
    pts: list = []
    trigs: list = []
    for shape in device_shapes(line):
        if shape.device.kind != "gate":
            continue
        d = shape.device
        after = next(c for c in line.conveyors if c.x_start_m >= d.x_end_m - 1e-9)
        left, right = (float(v) + s for v, s in zip(line.guide_y_at(np.array(d.x_m)), (0.02, -0.02)))
        bottom = shape.hinge_z_m - BIN_DEPTH_M
        for x, top, facing in ((shape.gap_from_m, shape.hinge_z_m - 0.04, 1.0), (after.x_start_m, after.z_top_m - 0.04, -1.0)):
            base = len(pts)
            pts += [[x, right, bottom], [x, left, bottom], [x, left, top], [x, right, top]]
            # (p1 - p0) x (p2 - p0) is +x for this order: flip it for a wall facing upstream
            trigs += ([[base, base + 1, base + 2], [base, base + 2, base + 3]] if facing > 0 else
                      [[base, base + 2, base + 1], [base, base + 3, base + 2]])
    return pts, trigs


def in_exit_regions(line: Line, x_m: np.ndarray, y_m: np.ndarray | None) -> np.ndarray:
    """True where (x, y) is in any device's :meth:`DeviceShape.region` (where the health checks let a fish be)."""
    out = np.zeros(np.shape(x_m), dtype=bool)
    for shape in device_shapes(line):
        out |= shape.region(x_m, y_m, line)
    return out


def going_out_sideways(line: Line, x_m: np.ndarray, y_m: np.ndarray, fish_of: np.ndarray) -> np.ndarray:
    """True for each body (x, y) beyond the guide line on the side of a pusher or diverter whose fish (``fish_of``, an
    index per body) has a body beyond that guide line along the device's opening: a fish going out through the
    opening, some of it swung round the end of the guide beside it (the health checks let it be there)."""
    out = np.zeros(np.shape(x_m), dtype=bool)
    if len(fish_of) == 0:
        return out
    for shape in device_shapes(line):
        if shape.opening is None:
            continue
        side = shape.opening[0]
        beyond = side * (y_m - line.guide_y_at(x_m)[0 if side > 0 else 1]) > 0.0
        at = np.zeros(int(fish_of.max()) + 1, dtype=bool)
        at[fish_of[beyond & shape.along(x_m)]] = True
        out |= beyond & at[fish_of]
    return out


def pusher_openings(line: Line) -> tuple[tuple[int, float, float], ...]:
    """(side, x from, x to) of every pusher's opening."""
    return tuple(s.opening for s in device_shapes(line) if s.device.kind == "pusher")


def guide_openings(line: Line) -> tuple[tuple[int, float, float], ...]:
    """(side, x from, x to) of every stretch of guide a device opens."""
    return tuple(s.opening for s in device_shapes(line) if s.opening is not None)


def exits(shapes: tuple[DeviceShape, ...], line: Line, x_m: np.ndarray, y_m: np.ndarray,
          z_m: np.ndarray) -> np.ndarray:
    """(n,) index of the device each mid-length point has left the line through, -1 for none (the first device
    in the line's order where zones overlap)."""
    out = np.full(np.shape(x_m), -1, dtype=np.int64)
    for i, shape in reversed(list(enumerate(shapes))):
        out[shape.exit_zone(x_m, y_m, z_m, line)] = i
    return out


DEVICE_STEP_FRACTION = 0.25
"""A device's fastest point may move at most this share of a fish's smallest contact sphere per integration step:
faster, it hits fish too hard for the step or passes through them."""


def device_step_limit_mps(step_s: float) -> float:
    """The fastest a device may move at integration step ``step_s``."""
    return DEVICE_STEP_FRACTION * MIN_SPHERE_RADIUS_M / step_s


SHORTEST_DEVICE_STEP_S = 0.00125
"""The shortest step a device makes the default one (the paper's fish's): a device faster than that allows is refused
naming its ``stroke_s``, not given a step many times shorter without a word."""


def step_for_devices(line: Line, comm_step_s: float, step_s: float) -> float:
    """The integration step for ``line``'s devices: ``step_s``, or where a device moves too fast for it the largest
    whole fraction of ``comm_step_s`` its fastest point allows (the joined fish's 2 ms with a reject gate swinging its
    0.43 m flap in 0.2 s: 1.25 ms), never below :data:`SHORTEST_DEVICE_STEP_S`."""
    fastest = max((shape.fastest_mps for shape in device_shapes(line)), default=0.0)
    if fastest <= device_step_limit_mps(step_s):
        return step_s
    n = int(np.ceil(comm_step_s * fastest / (DEVICE_STEP_FRACTION * MIN_SPHERE_RADIUS_M) - 1e-9))
    n_shortest = int(np.floor(comm_step_s / SHORTEST_DEVICE_STEP_S + 1e-9))
    return min(step_s, comm_step_s / max(1, min(n, n_shortest)))
