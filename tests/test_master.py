"""The co-simulation master on fake FMUs and a fake plant (no Exudyn, no compiled FMU): stepping
order, Gauss-Seidel and Jacobi coupling, ``step_multiple``, events, and the refusal of algebraic
loops.  Every expected value is worked out by hand in the test, with a communication step of
0.25 s so that the arithmetic is exact in binary floating point."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from plant.errors import InputError, SimulationError
from plant.sim.ports import PlantPorts
from plant.sim.state import PlantOutputs

from fishfmu.cosim.master import CoSimulation
from fishfmu.scenario.schema import Event
from fishfmu.scenario.order import direct_feedthrough, stepping_order as _topological
from fishfmu.scenario.wiring import PLANT, Connection, Port, Wiring

DT = 0.25


class FakeFmu:
    """What the master needs of an FMU (set/get/do_step/terminate); ``rule(t, dt, inputs, outputs)``
    gives the outputs at the end of a step.  Every step is logged with the inputs it was given."""

    def __init__(self, name: str, log: list[str], rule, outputs: dict) -> None:
        self.name, self.log, self.rule = name, log, rule
        self.out = dict(outputs)
        self.inputs: dict = {}
        self.steps: list[tuple[float, float, dict]] = []
        self.terminated = False

    def set(self, values: dict) -> None:
        self.inputs.update(values)

    def get(self, names: list[str]) -> dict:
        return {n: self.out[n] for n in names}

    def do_step(self, t_s: float, dt_s: float) -> None:
        self.steps.append((t_s, dt_s, dict(self.inputs)))
        self.log.append(self.name)
        self.out.update(self.rule(t_s, dt_s, self.inputs, self.out))

    def terminate(self) -> None:
        self.terminated = True

    def seen(self, var: str = "u") -> list:
        """The value of input ``var`` at each of its steps."""
        return [inputs[var] for _, _, inputs in self.steps]


def source(name: str, log: list[str]) -> FakeFmu:
    """Outputs the time at the end of its step: y = t + dt."""
    return FakeFmu(name, log, lambda t, dt, u, y: {"y": t + dt}, {"y": 0.0})


def gain(name: str, log: list[str], k: float) -> FakeFmu:
    """Direct feedthrough: y = k * u."""
    return FakeFmu(name, log, lambda t, dt, u, y: {"y": k * u["u"]}, {"y": 0.0})


def integrator(name: str, log: list[str]) -> FakeFmu:
    """State: y += u * dt."""
    return FakeFmu(name, log, lambda t, dt, u, y: {"y": y["y"] + u["u"] * dt}, {"y": 0.0})


class FakePlant:
    """The plant's side of the master: belt speeds in, ports out.  Records what it received; its
    belts run at the speed they are given, and pe1 is blocked when c1 runs faster than 1 m/s."""

    photoeye_ids = ["pe1"]

    def __init__(self, log: list[str], conveyors: tuple[str, ...] = ("c1",)) -> None:
        self.log = log
        self.conveyor_ids = list(conveyors)
        self.received: list[dict[str, float]] = []

    def step(self, speeds: dict[str, float], device_commands: dict[str, bool] | None = None) -> PlantOutputs:
        self.log.append(PLANT)
        self.received.append(dict(speeds))
        out = PlantOutputs(len(self.received) * DT, dict(speeds), {c: 0.5 * v for c, v in speeds.items()},
                           {c: 0.0 for c in speeds}, {"pe1": speeds["c1"] > 1.0})
        # what the master hands its step observers (the energy watch, the fish counts): no fish
        self.state = SimpleNamespace(outputs=out, status=np.zeros(0, dtype=np.int8))
        return out

    def speeds(self, conveyor: str = "c1") -> list[float]:
        return [s[conveyor] for s in self.received]


class WatchStub:
    """Stands in for the energy watch (which needs a real plant's fish): records its calls."""

    def __init__(self, log: list[str]) -> None:
        self.log = log
        self.calls: list[tuple[dict, dict, float]] = []

    def after_step(self, state, outputs, inputs, dt: float) -> None:
        self.check(state, dt)

    def check(self, state, dt: float) -> None:
        self.log.append("watch")
        self.calls.append((dict(state.outputs.belt_speed_mps), dict(state.outputs.belt_load_force_n), dt))


def port(key: str, causality: str, type_: str = "Real") -> Port:
    component, _, variable = key.partition(".")
    return Port(component, variable, causality, type_)


def connections(*pairs: str, types: dict[str, str] | None = None) -> list[Connection]:
    """``"A.y -> B.u"`` pairs as connections (Real unless ``types`` says otherwise, by source key)."""
    out = []
    for pair in pairs:
        a, b = (s.strip() for s in pair.split("->"))
        t = (types or {}).get(a, "Real")
        out.append(Connection(port(a, "output", t), port(b, "input", t)))
    return out


def cosim(fmus: list[FakeFmu], conns: list[Connection], plant: FakePlant, log: list[str], *,
          order: list[str] | None = None, constants: dict | None = None, **kw) -> CoSimulation:
    names = [f.name for f in fmus]
    wiring = Wiring(conns, order if order is not None else _topological(names, conns, None), constants or {})
    sim = CoSimulation(plant=plant, ports=PlantPorts(tuple(plant.conveyor_ids), tuple(plant.photoeye_ids)),
                       fmus={f.name: f for f in fmus}, step_multiples=kw.pop("step_multiples", {}),
                       wiring=wiring, events=kw.pop("events", []), comm_step_s=DT, **kw)
    sim.energy_watch = WatchStub(log)
    return sim


def run(sim: CoSimulation, n: int) -> None:
    for _ in range(n):
        sim.step()


# ---- (a)-(c) order and coupling -----------------------------------------------------------------
def test_gauss_seidel_steps_in_connection_order_and_passes_values_within_the_step():
    log: list[str] = []
    a, b, plant = source("A", log), gain("B", log, 2.0), FakePlant(log)
    conns = connections("A.y -> B.u", "B.y -> plant.c1.speed")
    # B listed first: the connection A -> B still puts A first
    sim = cosim([b, a], conns, plant, log)
    assert sim.wiring.order == ["A", "B"]
    run(sim, 3)
    assert log == ["A", "B", PLANT, "watch"] * 3
    assert [(t, dt) for t, dt, _ in a.steps] == [(0.0, DT), (0.25, DT), (0.5, DT)]
    # A's y after the step from t is t + 0.25; B sees it in the same step and doubles it
    assert b.seen() == [0.25, 0.5, 0.75]
    assert plant.speeds() == [0.5, 1.0, 1.5]
    frame = sim.signal_frame()
    assert list(frame.columns) == ["t_s", "A.y", "B.u", "B.y", "plant.c1.speed"]
    assert frame.values.tolist() == [[0.25, 0.25, 0.25, 0.5, 0.5], [0.5, 0.5, 0.5, 1.0, 1.0],
                                     [0.75, 0.75, 0.75, 1.5, 1.5]]


def test_gauss_seidel_in_the_other_order_delays_by_one_step():
    log: list[str] = []
    a, b, plant = source("A", log), gain("B", log, 2.0), FakePlant(log)
    sim = cosim([a, b], connections("A.y -> B.u", "B.y -> plant.c1.speed"), plant, log, order=["B", "A"])
    run(sim, 3)
    assert log == ["B", "A", PLANT, "watch"] * 3
    # B steps before A: it sees A's output of the previous step (0 after initialisation)
    assert b.seen() == [0.0, 0.25, 0.5]
    assert plant.speeds() == [0.0, 0.5, 1.0]


def test_jacobi_every_component_sees_the_previous_step():
    log: list[str] = []
    a, b, plant = source("A", log), gain("B", log, 2.0), FakePlant(log)
    sim = cosim([a, b], connections("A.y -> B.u", "B.y -> plant.c1.speed"), plant, log, jacobi=True,
                order=["A", "B"])
    run(sim, 4)
    # A.y after the steps: 0.25, 0.5, 0.75, 1.0; B sees it one step late, and the plant sees B's y
    # one step late: B.y after the steps is 0, 0.5, 1.0, 1.5
    assert [(t, dt) for t, dt, _ in a.steps] == [(0.0, DT), (0.25, DT), (0.5, DT), (0.75, DT)]
    assert b.seen() == [0.0, 0.25, 0.5, 0.75]
    assert plant.speeds() == [0.0, 0.0, 0.5, 1.0]


def test_plant_is_stepped_last_with_fresh_drive_output_and_fmus_read_it_one_step_late():
    log: list[str] = []
    s, drive, monitor, plant = source("S", log), gain("D", log, 2.0), gain("M", log, 1.0), FakePlant(log)
    conns = connections("S.y -> D.u", "D.y -> plant.c1.speed", "plant.c1.speed -> M.u",
                        "plant.c1.load_force -> S.u")
    sim = cosim([monitor, s, drive], conns, plant, log, order=["M", "S", "D"])
    run(sim, 3)
    assert log == ["M", "S", "D", PLANT, "watch"] * 3
    # the drive's output of this step reaches the plant in this step ...
    assert plant.speeds() == [0.5, 1.0, 1.5]
    # ... and the plant's output reaches the FMUs in the next one (at rest before the first step)
    assert monitor.seen() == [0.0, 0.5, 1.0]
    assert s.seen() == [0.0, 0.25, 0.5]  # load force: half the belt speed, one step late
    # the energy watch gets the plant's belt speeds and loads of this step
    assert sim.energy_watch.calls == [({"c1": v}, {"c1": 0.5 * v}, DT) for v in (0.5, 1.0, 1.5)]
    assert sim.values["plant.c1.speed"] == 1.5 and sim.values["plant.pe1.blocked"] is True


# ---- (d) step_multiple -------------------------------------------------------------------------
def test_step_multiple_steps_every_m_base_steps_with_m_times_the_step_and_holds_outputs():
    log: list[str] = []
    s, g, integ = source("S", log), gain("G", log, 2.0), integrator("I", log)
    plant = FakePlant(log, ("c1", "c2"))
    conns = connections("S.y -> G.u", "G.y -> plant.c1.speed", "I.y -> plant.c2.speed")
    sim = cosim([s, g, integ], conns, plant, log, constants={"I.u": 2.0}, step_multiples={"S": 3, "I": 3})
    run(sim, 7)
    big = 3 * DT
    assert [(t, dt) for t, dt, _ in s.steps] == [(0.0, big), (0.75, big), (1.5, big)]
    assert [(t, dt) for t, dt, _ in integ.steps] == [(0.0, big), (0.75, big), (1.5, big)]
    assert [(t, dt) for t, dt, _ in g.steps] == [(k * DT, DT) for k in range(7)]
    assert integ.seen() == [2.0, 2.0, 2.0]  # the constant input, set at each of its steps
    # S's y (its end-of-step time 0.75, 1.5, 2.25) held for the whole block of three base steps
    assert g.seen() == [0.75, 0.75, 0.75, 1.5, 1.5, 1.5, 2.25]
    assert plant.speeds("c1") == [1.5, 1.5, 1.5, 3.0, 3.0, 3.0, 4.5]
    # the integrator adds 2 * 0.75 = 1.5 per step of its own
    assert plant.speeds("c2") == [1.5, 1.5, 1.5, 3.0, 3.0, 3.0, 4.5]
    assert log[:9] == ["S", "G", "I", PLANT, "watch", "G", PLANT, "watch", "G"]


# ---- (e) events --------------------------------------------------------------------------------
def test_events_override_bias_and_reset_from_their_step_on():
    log: list[str] = []
    a, b, plant = source("A", log), gain("B", log, 1.0), FakePlant(log)
    events = [Event(t_s=0.5, target="B.u", action="override", value=10.0),
              Event(t_s=1.0, target="B.u", action="reset"),
              Event(t_s=1.25, target="A.y", action="bias", value=1.0),
              Event(t_s=1.75, target="A.y", action="reset")]
    sim = cosim([a, b], connections("A.y -> B.u", "B.y -> plant.c1.speed"), plant, log, events=list(reversed(events)))
    run(sim, 8)
    # step at t:      0     0.25  0.5   0.75  1.0   1.25       1.5         1.75
    # A.y after it:   0.25  0.5   0.75  1.0   1.25  1.5        1.75        2.0
    # B.u:                        override    reset bias +1    bias +1     reset
    assert b.seen() == [0.25, 0.5, 10.0, 10.0, 1.25, 2.5, 2.75, 2.0]
    assert plant.speeds() == [0.25, 0.5, 10.0, 10.0, 1.25, 2.5, 2.75, 2.0]
    assert sim.overrides == {}
    # a bias on a source acts on what is sent, not on the FMU's own value; recorded as sent
    frame = sim.signal_frame()
    assert frame["B.u"].tolist() == b.seen()
    assert frame["A.y"].tolist()[5] == 1.5


def test_events_on_plant_ports_and_constant_inputs():
    log: list[str] = []
    monitor, flag = gain("M", log, 1.0), FakeFmu("F", log, lambda t, dt, u, y: {}, {})
    plant = FakePlant(log)
    conns = connections("plant.c1.speed -> M.u", "plant.pe1.blocked -> F.b", types={"plant.pe1.blocked": "Boolean"})
    events = [Event(t_s=0.25, target="plant.c1.speed", action="bias", value=0.5),
              Event(t_s=0.5, target="plant.pe1.blocked", action="override", value=True),
              Event(t_s=0.75, target="plant.c1.speed", action="override", value=1.0),
              Event(t_s=1.0, target="plant.c1.speed", action="reset"),
              Event(t_s=1.0, target="plant.pe1.blocked", action="reset")]
    sim = cosim([monitor, flag], conns, plant, log, constants={"plant.c1.speed": 0.25}, events=events)
    run(sim, 5)
    # the constant belt speed 0.25, biased by 0.5 from t = 0.25, overridden with 1 from 0.75, reset at 1.0
    assert plant.speeds() == [0.25, 0.75, 0.75, 1.0, 0.25]
    assert all(type(v) is float for v in plant.speeds())
    # the event acts on the plant's output as FMUs read it too: the plant's speed of the previous
    # step (at rest: 0), with this step's bias or override
    assert monitor.seen() == [0.0, 0.75, 1.25, 1.0, 1.0]
    assert flag.seen("b") == [False, False, True, True, False]
    assert all(type(v) is bool for v in flag.seen("b"))


def test_nan_output_of_an_fmu_stops_the_run_naming_it_and_terminate_reaches_every_fmu():
    log: list[str] = []
    bad = FakeFmu("bad", log, lambda t, dt, u, y: {"y": math.nan if t > 0 else 1.0}, {"y": 0.0})
    plant = FakePlant(log)
    sim = cosim([bad], connections("bad.y -> plant.c1.speed"), plant, log)
    sim.step()
    with pytest.raises(SimulationError, match="FMU 'bad': output 'y' is nan") as info:
        sim.step()
    assert info.value.time_s == 0.5
    assert plant.speeds() == [1.0]
    sim.terminate()
    assert bad.terminated


# ---- (f) algebraic loops -----------------------------------------------------------------------
LOOP = connections("A.y -> B.u", "B.y -> C.u", "C.y -> A.u")


def test_a_loop_of_direct_feedthrough_outputs_is_refused():
    feed = {"A": {"y"}, "B": {"y"}, "C": {"y"}}
    with pytest.raises(InputError, match=r"algebraic loop: A -> B -> C -> A .*jacobi") as info:
        _topological(["A", "B", "C"], LOOP, "s.toml", feed)
    assert "s.toml" in str(info.value) and "wiring.connections" in str(info.value)


def test_a_loop_with_one_state_output_is_ordered_first_listed_first():
    feed = {"A": {"y"}, "B": {"y"}}  # C.y depends on C's state only
    assert _topological(["A", "B", "C"], LOOP, None, feed) == ["A", "B", "C"]
    assert _topological(["B", "A", "C"], LOOP, None, feed) == ["B", "C", "A"]
    assert _topological(["C", "B", "A"], LOOP, None) == ["C", "A", "B"]
    # a feedthrough output outside any loop is no problem
    assert _topological(["B", "A"], connections("A.y -> B.u"), None, {"A": {"y"}, "B": {"y"}}) == ["A", "B"]


def test_direct_feedthrough_reads_the_declared_dependencies_on_inputs():
    u, x = SimpleNamespace(name="u", causality="input"), SimpleNamespace(name="x", causality="local")
    out = [SimpleNamespace(variable=SimpleNamespace(name=n), dependencies=d)
           for n, d in (("y_direct", [u, x]), ("y_state", [x]), ("y_undeclared", None), ("y_none", []))]
    md = SimpleNamespace(modelVariables=[u, x], outputs=out)
    assert direct_feedthrough(md) == {"y_direct"}
