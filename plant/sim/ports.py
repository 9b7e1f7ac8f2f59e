"""The plant's ports, declared once: what goes in (belt speeds, device commands) and what comes out (sensor readings).

Every conveyor ``c`` and photo-eye ``p`` of the line gives ports named ``<id>.<signal>``:

- ``c.speed`` (Real, m/s): in, the belt surface speed for the coming step; out, the speed it ran at;
- ``c.load_force`` (Real, N): out, the fish's force on the belt against its motion;
- ``c.load_mass`` (Real, kg): out, the mass resting on the belt;
- ``p.blocked`` (Boolean): out, whether a fish cuts the beam;
- for every camera ``k`` (outputs, what its last result said, see :mod:`plant.sim.camera`): ``k.count`` (Integer,
  fish in view), ``k.double`` (Boolean), ``k.lead_double`` (Boolean: the leading fish is one of a double),
  ``k.lead_x`` (Real, m: front end of the leading fish, the one furthest downstream), ``k.lead_length`` (Real, m),
  ``k.lead_heading`` (Integer: 1 head first, -1 tail first, 0 no fish), ``k.events`` (Integer: fish seen so far),
  ``k.results`` (Integer: results given so far);
- for every device ``d`` (:mod:`plant.contract.devices`): ``d.command`` (Boolean, in only: true moves it to the end of
  its travel, false home), ``d.position`` (Real, 0 home to 1 at the end of its travel), ``d.at_home`` and
  ``d.at_end`` (Boolean: its limit switches), ``d.rejected`` (Integer: fish it has taken off the line so far).

Everything that names the plant's ports derives them from :data:`SIGNALS` and :class:`PlantPorts`: the
plant's outputs (:meth:`plant.sim.state.PlantOutputs.port_values`), a scenario's wiring
(``fishfmu.scenario.wiring``), the co-simulation master, the plant FMU and ``fishfmu serve``.

>>> from plant.contract.line import Line
>>> line = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
...     {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0}],
...     "photoeyes": [{"id": "pe1", "x_m": 1.5, "z_m": 0.015}]})
>>> ports = PlantPorts.of(line)
>>> ports.inputs(), ports.outputs()
(['c1.speed'], ['c1.speed', 'c1.load_force', 'c1.load_mass', 'pe1.blocked'])
>>> SIGNALS["load_force"].unit, signal_of("pe1.blocked").type
('N', 'Boolean')
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from plant.contract.line import Line


@dataclass(frozen=True)
class Signal:
    """One kind of port, had by every conveyor or every photo-eye."""

    name: str
    of: str
    """``conveyor``, ``photoeye``, ``camera`` or ``device``: whose port it is."""
    type: str
    """FMI-style type name of its values: ``Real`` (float), ``Integer`` (int) or ``Boolean`` (bool)."""
    unit: str | None
    unit_base: tuple[float, ...] | None
    """The unit in SI base units (kg, m, s, A, K, mol, cd, rad, factor, offset), as an FMU defines one."""
    is_input: bool
    field: str
    """The :class:`~plant.sim.state.PlantOutputs` field holding its output values, by id ("" for an input only)."""
    description: str
    is_output: bool = True
    at_rest: float | int | bool | None = None
    """Its output before the first step (belts stopped, beams clear, nothing seen, devices home); None: the type's
    zero."""

    @property
    def rest_value(self) -> float | int | bool:
        if self.at_rest is not None:
            return self.at_rest
        return {"Real": 0.0, "Integer": 0, "Boolean": False}[self.type]


SIGNALS: dict[str, Signal] = {s.name: s for s in (
    Signal("speed", "conveyor", "Real", "m/s", (0, 1, -1, 0, 0, 0, 0, 0, 1.0, 0.0), True, "belt_speed_mps",
           "belt surface speed: in, for the coming step; out, the speed it ran at"),
    Signal("load_force", "conveyor", "Real", "N", (1, 1, -2, 0, 0, 0, 0, 0, 1.0, 0.0), False, "belt_load_force_n",
           "the fish's force on the belt against its motion"),
    Signal("load_mass", "conveyor", "Real", "kg", (1, 0, 0, 0, 0, 0, 0, 0, 1.0, 0.0), False, "belt_load_mass_kg",
           "mass resting on the belt"),
    Signal("blocked", "photoeye", "Boolean", None, None, False, "photoeyes", "a fish cuts the beam"),
    Signal("count", "camera", "Integer", None, None, False, "camera_count", "fish in the camera's view"),
    Signal("double", "camera", "Boolean", None, None, False, "camera_double",
           "two fish in view overlap or are closer than the camera's double_gap_m along the line"),
    Signal("lead_double", "camera", "Boolean", None, None, False, "camera_lead_double",
           "the leading fish has been one of a double (overlapping another fish in view or closer to it than "
           "double_gap_m) in a frame since it came into view"),
    Signal("lead_x", "camera", "Real", "m", (0, 1, 0, 0, 0, 0, 0, 0, 1.0, 0.0), False, "camera_lead_x_m",
           "front end of the leading fish in view (the one furthest downstream); 0 with none in view"),
    Signal("lead_length", "camera", "Real", "m", (0, 1, 0, 0, 0, 0, 0, 0, 1.0, 0.0), False, "camera_lead_length_m",
           "length of the leading fish as seen from above (snout to tail tip); 0 with none in view"),
    Signal("lead_heading", "camera", "Integer", None, None, False, "camera_lead_heading",
           "the leading fish comes head first (1) or tail first (-1); 0 with none in view"),
    Signal("events", "camera", "Integer", None, None, False, "camera_events",
           "fish the camera has seen so far: steps by one each time a new fish comes into view"),
    Signal("results", "camera", "Integer", None, None, False, "camera_results",
           "results the camera has given so far: steps by one with each new result (a frame's, after its latency)"),
    Signal("command", "device", "Boolean", None, None, True, "",
           "true: move to the end of the travel (open the gate, stroke the pusher, swing the arm); false: home", False),
    Signal("position", "device", "Real", None, None, False, "device_position",
           "where the device is along its travel: 0 home, 1 at its end"),
    Signal("at_home", "device", "Boolean", None, None, False, "device_at_home", "limit switch: the device is home",
           at_rest=True),
    Signal("at_end", "device", "Boolean", None, None, False, "device_at_end",
           "limit switch: the device is at the end of its travel"),
    Signal("rejected", "device", "Integer", None, None, False, "device_rejected",
           "fish the device has taken off the line so far"),
)}
"""Every signal of the plant's ports, conveyors' first; each conveyor's, each photo-eye's and each camera's ports
come in this order."""


KINDS = ("conveyor", "photoeye", "camera", "device")
"""The kinds of the line's equipment that have ports, in the order their ports come."""


def signal_of(port: str) -> Signal:
    """The signal of a port name ``<id>.<signal>`` (KeyError if the plant has no such signal)."""
    return SIGNALS[port.rpartition(".")[2]]


@dataclass(frozen=True)
class PlantPorts:
    """The ports of one line's plant: per conveyor, per photo-eye, per camera and per device, in the line's order."""

    conveyor_ids: tuple[str, ...]
    photoeye_ids: tuple[str, ...]
    camera_ids: tuple[str, ...] = ()
    device_ids: tuple[str, ...] = ()

    @classmethod
    def of(cls, line: Line) -> PlantPorts:
        return cls(tuple(c.id for c in line.conveyors), tuple(p.id for p in line.photoeyes),
                   tuple(c.id for c in line.cameras), tuple(d.id for d in line.devices))

    def ids_of(self, of: str) -> tuple[str, ...]:
        """The ids of the units of one kind (a :attr:`Signal.of`)."""
        return {"conveyor": self.conveyor_ids, "photoeye": self.photoeye_ids, "camera": self.camera_ids,
                "device": self.device_ids}[of]

    def _names(self, signals: Iterable[Signal]) -> list[str]:
        signals = list(signals)
        return [f"{i}.{s.name}" for of in KINDS for i in self.ids_of(of) for s in signals if s.of == of]

    def inputs(self) -> list[str]:
        """Input port names (every conveyor's ``speed``, every device's ``command``)."""
        return self._names(s for s in SIGNALS.values() if s.is_input)

    def outputs(self, signals: Iterable[str] | None = None) -> list[str]:
        """Output port names: every conveyor's, then every photo-eye's, camera's and device's, or only those of the
        named ``signals``."""
        return self._names(s for s in (SIGNALS.values() if signals is None else map(SIGNALS.__getitem__, signals))
                           if s.is_output)
