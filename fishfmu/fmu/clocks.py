"""FMI 3.0 periodic input clocks (a PLC task as a clock): which clocks fishfmu ticks, and when.

An input clock whose modelDescription gives its period (``intervalVariability`` constant or fixed, with
``intervalDecimal``; ``shiftDecimal`` defaulting to 0) ticks at start + shift + k x interval, k = 0, 1, ... (each
time computed from k, so that ticks do not drift).  The master steps the FMU to each tick, enters event mode, sets
the clock active (``fmi3SetClock``) and updates the discrete states (:mod:`fishfmu.fmu.instance`); the FMU deactivates
it again when it leaves event mode.  Other clocks are refused with the reason (:func:`clock_problem`): output clocks
(nothing in fishfmu takes their ticks), triggered, tunable, changing or countdown clocks (their ticks are not known
from the model description), and any clock of an FMU without event mode.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from lxml import etree

PERIODIC = ("constant", "fixed")


def clock_attributes(unzip_dir_or_xml: Path | bytes) -> dict[str, dict[str, str]]:
    """Every Clock variable's attributes by name, read from the modelDescription (fmpy 0.3.32 does not read a clock's
    interval or shift)."""
    data = unzip_dir_or_xml if isinstance(unzip_dir_or_xml, bytes) else \
        (Path(unzip_dir_or_xml) / "modelDescription.xml").read_bytes()
    root = etree.fromstring(data, etree.XMLParser(resolve_entities=False, no_network=True))
    return {c.get("name"): dict(c.attrib) for c in root.iterfind("ModelVariables/Clock")}


def clock_problem(attrs: dict[str, str], has_event_mode: bool) -> str | None:
    """Why fishfmu cannot tick this clock, or None."""
    if not has_event_mode:
        return "a clock of an FMU without event mode"
    if attrs.get("causality") != "input":
        return "an output clock (nothing in fishfmu takes its ticks)"
    variability = attrs.get("intervalVariability")
    if variability not in PERIODIC or attrs.get("intervalDecimal") is None:
        return (f"an input clock with intervalVariability = {variability} and no intervalDecimal (fishfmu ticks "
                "periodic clocks whose interval the model description gives)")
    if not float(attrs["intervalDecimal"]) > 0.0:
        return f"a periodic clock with interval {attrs['intervalDecimal']}"
    return None


@dataclass
class PeriodicClocks:
    """The periodic input clocks of one instance and the next tick of each."""

    value_references: list[int]
    interval_s: list[float]
    shift_s: list[float]
    start_s: float
    ticks: list[int] = field(default_factory=list)
    """How many times each clock has ticked."""

    @classmethod
    def of(cls, attributes: dict[str, dict[str, str]], start_s: float) -> PeriodicClocks:
        clocks = list(attributes.values())
        return cls([int(c["valueReference"]) for c in clocks], [float(c["intervalDecimal"]) for c in clocks],
                   [float(c.get("shiftDecimal", "0")) for c in clocks], start_s, [0] * len(clocks))

    def _tick_s(self, i: int) -> float:
        return self.start_s + self.shift_s[i] + self.ticks[i] * self.interval_s[i]

    def next_tick_s(self) -> float | None:
        return min((self._tick_s(i) for i in range(len(self.ticks))), default=None)

    def due(self, t_s: float) -> list[int]:
        """The value references of the clocks that tick at or before ``t_s`` (each counted as ticked)."""
        out = []
        for i, vr in enumerate(self.value_references):
            if self._tick_s(i) <= t_s:
                out.append(vr)
                self.ticks[i] += 1
        return out

