"""``fishfmu export-fmu``: the plant of a scenario (line, fish, drops, extensions) as an FMI 2.0 co-simulation FMU,
for other masters (libcosim, OMSimulator, Simulink, TwinCAT...).

The FMU is made by pythonfmu: its ``resources/`` hold the slave script (:mod:`fishfmu.cosim.plant_fmu_slave`, copied
as ``fishfmu_plant.py``) and the scenario as resolved; the slave builds a :class:`PlantInFmu` from them, which runs
fishfmu's Exudyn plant. **Runtime requirement**: the host must load the FMU into a process where Python 3.11 runs
with fishfmu (and so Exudyn) installed, as pythonfmu FMUs need the host's Python; the FMU does not carry Python or
Exudyn.

Variables (the plant's ports as declared in :mod:`plant.sim.ports`, named as in a scenario's wiring):

* inputs ``<conveyor>.speed`` (m/s, within ±:data:`~plant.contract.plausibility.MAX_BELT_SPEED_MPS`) for every conveyor,
  ``<device>.command`` (Boolean) for every device;
* outputs ``<photo-eye>.blocked`` (Boolean), ``<conveyor>.load_force`` (N), ``<conveyor>.load_mass`` (kg), each
  camera's ``<camera>.count``, ``.double``, ``.lead_x``, ``.lead_length``, ``.lead_heading``, ``.events`` (Integer,
  Boolean or Real as declared), each device's ``<device>.position``, ``.at_home``, ``.at_end``, ``.rejected`` (every
  output port but the belt speed, which is the input), and counts so far: ``fish_dropped``,
  ``fish_on_line``, ``fish_left`` (gone past the end or off the line), ``fish_rejected`` (taken off by a device),
  ``outfeed_count`` (fish heads seen at the scenario's outfeed photo-eye: its blocked edges);
* parameters ``seed`` and ``fish_count`` (fixed, within a scenario's bounds for ``run.seed`` and ``fish.count``;
  the batch is sampled from them as ``fishfmu run`` samples it).

After each plant step it attaches what a run attaches (:func:`plant.sim.observers.plant_observers`): the energy
watch (a blow-up is a stop: that doStep returns fmi2Discard and the steps after it are refused) and the fish counts;
not the recording (the host records what it wants of the FMU's outputs; the FMU writes no files).

A ``doStep`` of h advances the plant h / ``run.comm_step_s`` steps with the belt speeds last set (h must be a
whole multiple of the scenario's communication step, at most :data:`MAX_STEP_S`).

**Bad input never crashes the host.** pythonfmu (0.7) turns any Python exception into fmi2Fatal and frees the
slave, so that the host's next call (fmi2GetReal, fmi2Terminate) crashes the host's process; its set functions
have no failure status but fmi2Fatal, and the only other failure its doStep has is fmi2Discard (``do_step``
returning False; the FMU then reports fmi2Terminated = true). So no exception leaves the slave. A value outside
the bounds the model description declares (min, max), or a variable that cannot be set, is refused: an
error-status log message names the variable and the value it keeps. Each doStep while a refusal stands, before
initialisation, after the plant stopped (a blow-up), or with a step that is not a positive whole multiple of the
communication step, returns fmi2Discard with an error-status log message and leaves the plant as it was.
fmi2Reset gives a fresh slave: it is initialised again before it steps.
"""

from __future__ import annotations

import functools
import math
import tomllib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import tomli_w
from pydantic import BaseModel

from plant.contract.parts import part_triangles, read_stl_bytes
from plant.errors import InputError, SimulationError, one_line
from plant.sim.observers import StepInputs, StepObserver, notify, plant_observers
from plant.sim.plant import Plant
from plant.sim.ports import PlantPorts, signal_of
from plant.contract.plausibility import MAX_BELT_SPEED_MPS
from plant.fish.population import PopulationSpec

from fishfmu.cosim.build import scenario_fish
from fishfmu.scenario.schema import RunSettings, Scenario, load_scenario, resolved_toml

SLAVE_SOURCE = Path(__file__).with_name("plant_fmu_slave.py")
"""The pythonfmu slave script the FMU carries (:mod:`fishfmu.cosim.plant_fmu_slave`)."""

SCENARIO_RESOURCE = "scenario.toml"
PARTS_RESOURCE = "parts"
"""The folder of ``resources/`` that holds the line's STL parts (named relative to ``scenario.toml``)."""
BUG = "a bug in fishfmu; please report it"
FMI_INTEGER_MAX = 2**31 - 1
"""fmi2Integer is a C int: a larger seed cannot be set through FMI."""


def field_bounds(model: type[BaseModel], name: str) -> tuple[Any, Any]:
    """The inclusive bounds (``ge``, ``le``; None where absent) of a field of a scenario table: the FMU declares
    and checks the bounds a scenario file has."""
    lo = hi = None
    for constraint in model.model_fields[name].metadata:
        lo, hi = getattr(constraint, "ge", lo), getattr(constraint, "le", hi)
    return lo, hi


_SEED_MIN, _SEED_MAX = field_bounds(RunSettings, "seed")
SEED_BOUNDS = (_SEED_MIN, min(_SEED_MAX, FMI_INTEGER_MAX))
FISH_COUNT_BOUNDS = field_bounds(PopulationSpec, "count")
SPEED_BOUNDS_MPS = (-MAX_BELT_SPEED_MPS, MAX_BELT_SPEED_MPS)
MAX_STEP_S = field_bounds(RunSettings, "duration_s")[1]
"""Longest doStep: the longest run a scenario may ask for (a doStep of 1e9 s would hold the host for years)."""
PARAMETER_BOUNDS = {"seed": SEED_BOUNDS, "fish_count": FISH_COUNT_BOUNDS}


def _num(x: float) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def with_bounds(var: Any, bounds: tuple[Any, Any]) -> Any:
    """``var``, a pythonfmu variable, declaring ``min`` and ``max`` in the model description (pythonfmu 0.7's
    variables write only ``start``)."""
    to_xml = var.to_xml

    def to_xml_with_bounds():  # noqa: ANN202 - returns an ElementTree element
        node = to_xml()
        node[0].set("min", repr(bounds[0]))  # node[0]: the <Real>/<Integer> element
        node[0].set("max", repr(bounds[1]))
        return node
    var.to_xml = to_xml_with_bounds
    return var


def never_raises(fallback: Callable[..., Any]) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Decorate an FMI entry point of the slave: an exception is logged as an internal error (``self.log_error``)
    and ``fallback(*args)`` returned, as pythonfmu would turn it into fmi2Fatal and crash the host's next call."""
    def wrap(method: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(method)
        def guarded(self, *args):  # noqa: ANN001, ANN202 - any entry point
            try:
                return method(self, *args)
            except Exception as exc:  # noqa: BLE001 - any exception would crash the host
                self.log_error(one_line(f"internal error in {method.__name__} ({BUG}): {exc!r}"))
                return fallback(*args)
        return guarded
    return wrap


class PlantInFmu:
    """The plant behind the FMU's variables: built from the scenario at initialisation, stepped by doStep.

    No method raises (see the module's docstring): what the host got wrong is passed to ``report`` (the slave's
    error log) and refused."""

    counts = ("fish_dropped", "fish_on_line", "fish_left", "fish_rejected", "outfeed_count")
    """The fish counts it exports: those of :class:`plant.sim.observers.FishCounts` (``serve`` shows
    ``fish_waiting`` where this has ``fish_dropped``: the batch's count less it)."""

    def __init__(self, scenario_file: Path, report: Callable[[str], None],
                 observers: Sequence[StepObserver] = ()) -> None:
        self.report = report
        self.observers = list(observers)
        """Step observers attached after the energy watch and the fish counts (a script's own)."""
        self.scenario: Scenario = load_scenario(scenario_file)
        self.comm_step_s = self.scenario.run.comm_step_s
        self.outfeed = self.scenario.kpi.outfeed_photoeye
        ports = PlantPorts.of(self.scenario.line)
        self.conveyor_ids, self.device_ids = list(ports.conveyor_ids), list(ports.device_ids)
        self.input_names = ports.inputs()
        self.command_names = [f"{d}.command" for d in self.device_ids]
        outputs = [n for n in ports.outputs() if n not in self.input_names]  # a belt's speed is its input
        plant_outputs = ([n for n in outputs if signal_of(n).of == "photoeye"]  # the photo-eyes first
                         + [n for n in outputs if signal_of(n).of == "conveyor"]
                         + [n for n in outputs if signal_of(n).of in ("camera", "device")])
        self.plant_outputs = set(plant_outputs)
        self.output_names = plant_outputs + list(self.counts)
        self.values: dict[str, Any] = {"seed": self.scenario.run.seed, "fish_count": self.scenario.fish.count}
        self.values.update({n: False if n in self.command_names else 0.0 for n in self.input_names})
        self.values.update({n: {"Boolean": False, "Integer": 0}.get(signal_of(n).type, 0.0) for n in plant_outputs})
        self.values.update(dict.fromkeys(self.counts, 0))
        self.units = {n: signal_of(n).unit for n in self.input_names + plant_outputs if signal_of(n).unit}
        self.refused: dict[str, str] = {}
        """Variable -> why its last set was refused; each doStep is refused while one stands."""
        self.initialised = False
        self.failure: str | None = None
        """Why the plant could not be built or stopped: the doSteps after it are refused."""
        self.plant: Plant | None = None
        self.watches: list = []
        """The step observers attached as a run attaches them, without the recording
        (:func:`plant.sim.observers.plant_observers`)."""

    def getter(self, name: str):  # noqa: ANN201 - pythonfmu takes any callable
        return lambda: self.values[name]

    def speed_setter(self, name: str):  # noqa: ANN201
        def set_(value: float) -> None:
            self._set_within(name, float(value), SPEED_BOUNDS_MPS, " m/s")
        return set_

    def command_setter(self, name: str):  # noqa: ANN201
        def set_(value: bool) -> None:
            self.values[name] = bool(value)
        return set_

    def parameter_setter(self, name: str):  # noqa: ANN201
        def set_(value: int) -> None:
            if self.initialised and value != self.values[name]:
                self.refuse(name, f"{name} = {value} refused: {name} is fixed once initialised "
                                  f"(fmi2ExitInitializationMode); it stays {self.values[name]} (fmi2Reset to change it)")
            else:
                self._set_within(name, int(value), PARAMETER_BOUNDS[name], "")
        return set_

    def _set_within(self, name: str, value: float, bounds: tuple[Any, Any], unit: str) -> None:
        lo, hi = bounds
        if math.isfinite(value) and lo <= value <= hi:
            self.values[name] = value
            self.refused.pop(name, None)
        else:
            self.refuse(name, f"{name} = {_num(value)}{unit} refused: it must be within [{_num(lo)}, {_num(hi)}]{unit}; "
                              f"it stays {_num(self.values[name])}{unit}")

    def refuse(self, name: str, message: str) -> None:
        self.refused[name] = message
        self.report(one_line(message))

    def start(self) -> None:
        """fmi2ExitInitializationMode: the plant with the fish of the parameters set (not built while a parameter's
        refusal stands: doStep then names it)."""
        self.initialised = True
        refused = [m for name, m in self.refused.items() if name in PARAMETER_BOUNDS]
        if refused:
            self.failure = "the plant was not built: " + "; ".join(refused)
            return
        sc = self.scenario.model_copy(deep=True)
        try:
            sc.run.seed, sc.fish.count = self.values["seed"], self.values["fish_count"]
            self.plant = Plant(sc.line, scenario_fish(sc), sc.plant, sc.run.comm_step_s, seed=sc.run.seed)
            self.watches = [*plant_observers(self.outfeed), *self.observers]
        except (InputError, SimulationError) as exc:
            self.failure = (f"the plant could not be built with seed = {self.values['seed']} and "
                            f"fish_count = {self.values['fish_count']}: {exc}")
        except Exception as exc:  # noqa: BLE001 - an exception would crash the host (module docstring)
            self.failure = f"internal error building the plant ({BUG}): {exc!r}"
        if self.failure:
            self.report(one_line(self.failure))

    def do_step(self, step_size_s: float) -> bool:
        """fmi2DoStep: True once the plant advanced ``step_size_s``; False (fmi2Discard), the reason logged, when it
        cannot (the plant untouched) or stopped on the way (the steps after are refused)."""
        reason = self._why_not(step_size_s)
        if reason is None:
            try:
                self._advance(round(step_size_s / self.comm_step_s))
                return True
            except SimulationError as exc:
                self.failure = reason = f"the plant stopped: {exc}"
            except Exception as exc:  # noqa: BLE001 - an exception would crash the host (module docstring)
                self.failure = reason = f"internal error stepping the plant ({BUG}): {exc!r}"
        self.report(one_line(f"doStep(h = {_num(float(step_size_s))} s) not done: {reason}"))
        return False

    def _why_not(self, step_size_s: float) -> str | None:
        if self.refused:
            return "; ".join(self.refused.values())
        if self.failure:
            return f"{self.failure} (fmi2Reset and initialise again to start over)"
        if self.plant is None:
            return ("the plant is not initialised: call fmi2EnterInitializationMode and fmi2ExitInitializationMode "
                    "first (after fmi2Instantiate or fmi2Reset)")
        h = float(step_size_s)
        if not (math.isfinite(h) and 0.0 < h <= MAX_STEP_S):
            return f"the step must be positive, finite and at most {_num(MAX_STEP_S)} s"
        n = h / self.comm_step_s
        if round(n) < 1 or abs(n - round(n)) > 1e-6:
            return f"the step must be a whole multiple of the communication step ({_num(self.comm_step_s)} s)"
        return None

    def _advance(self, n_steps: int) -> None:
        speeds = {c: self.values[f"{c}.speed"] for c in self.conveyor_ids}
        commands = {d: bool(self.values[f"{d}.command"]) for d in self.device_ids}
        inputs = StepInputs(speeds, commands, speeds)  # the host sets the speeds: they are the setpoints here
        for _ in range(n_steps):
            out = self.plant.step(speeds, commands)
            # as in a run: the energy watch stops a blow-up (fmi2Discard, the steps after refused), then the counts
            notify(self.watches, self.plant.state, out, inputs, self.comm_step_s)
            for port, v in out.port_values().items():
                if port in self.plant_outputs:
                    self.values[port] = v
        counted = self.watches[1].values
        self.values.update((name, counted[name]) for name in self.counts)


def export_plant_fmu(scenario: Scenario, folder: Path) -> Path:
    """Build the plant FMU of ``scenario`` with pythonfmu into ``folder`` (a temporary one: the caller moves it);
    the scenario inside keeps what the plant needs (run, line, fish, plant, kpi), not the FMUs, wiring, events and
    ``[opcua]`` inputs: a served scenario exports its plant, whose belt speeds and device commands the host sets."""
    try:  # pythonfmu: only to export, and optional (a test extra, not one of fishfmu's dependencies)
        from pythonfmu.builder import FmuBuilder
    except ImportError:
        raise InputError("export-fmu needs pythonfmu (pip install pythonfmu)") from None
    if not SEED_BOUNDS[0] <= scenario.run.seed <= SEED_BOUNDS[1]:
        raise InputError(f"{scenario.run.seed}: the plant FMU's seed is an FMI Integer, at most {SEED_BOUNDS[1]}",
                         where="run.seed")
    doc = tomllib.loads(resolved_toml(scenario))
    plant_only = {k: doc[k] for k in ("run", "line", "fish", "plant", "kpi") if k in doc}
    script = folder / "fishfmu_plant.py"
    # the slave module (which imports this one) is copied as a file into the FMU, not imported here
    script.write_text(SLAVE_SOURCE.read_text(encoding="utf-8"), encoding="utf-8")
    resource = folder / "res" / SCENARIO_RESOURCE
    resource.parent.mkdir()
    parts = carry_parts(scenario, plant_only, folder / "res" / PARTS_RESOURCE)
    resource.write_text(tomli_w.dumps(plant_only), encoding="utf-8")
    return Path(FmuBuilder.build_FMU(script, dest=folder / "built", project_files=[resource, *parts]))


def carry_parts(scenario: Scenario, plant_only: dict[str, Any], folder: Path) -> list[Path]:
    """Copy the line's STL parts (checked as a run checks them) into ``folder`` (``resources/parts/`` of the FMU) and
    name them relative to the FMU's scenario in ``plant_only``: the FMU runs with its parts wherever it is moved, and
    carries no path of the exporting machine.  Returns ``[folder]``, or ``[]`` for a line without parts."""
    part_triangles(scenario.line)  # every file readable, within the limits and over the line
    if not scenario.line.parts:
        return []
    folder.mkdir()
    for i, part in enumerate(scenario.line.parts):
        name = f"{i}_{part.id}.stl"  # ids are unique and safe as file names (the schema's Id pattern)
        (folder / name).write_bytes(read_stl_bytes(part.stl, f"line.parts[{i}].stl"))
        plant_only["line"]["parts"][i]["stl"] = f"{PARTS_RESOURCE}/{name}"
    return [folder]
