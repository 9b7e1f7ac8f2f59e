"""``fishfmu export-fmu``: the plant of a scenario (line, fish, drops, extensions) as an FMI 2.0 co-simulation FMU,
for other masters (libcosim, OMSimulator, Simulink, TwinCAT...).

The FMU is made by pythonfmu: its ``resources/`` hold a small slave script (:data:`SLAVE_SCRIPT`) and the
scenario as resolved; the slave builds a :class:`PlantInFmu` from them, which runs fishfmu's Exudyn plant.
**Runtime requirement**: the host must load the FMU into a process where Python 3.11 runs with fishfmu (and
so Exudyn) installed, as pythonfmu FMUs need the host's Python; the FMU does not carry Python or Exudyn.

Variables (named as the plant's ports in a scenario's wiring):

* inputs ``<conveyor>.speed`` (m/s) for every conveyor;
* outputs ``<photo-eye>.blocked`` (Boolean), ``<conveyor>.load_force`` (N), ``<conveyor>.load_mass`` (kg),
  and counts so far: ``fish_dropped``, ``fish_on_line``, ``fish_left`` (gone past the end or off the line),
  ``outfeed_count`` (fish heads seen at the scenario's outfeed photo-eye: its blocked edges);
* parameters ``seed`` and ``fish_count`` (fixed; the batch is sampled from them as ``fishfmu run`` samples it).

A ``doStep`` of h advances the plant h / ``run.comm_step_s`` steps with the belt speeds last set (h must be a
whole multiple of the scenario's communication step).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from plant.errors import InputError
from plant.plant import LEFT, ON_LINE, WAITING, Plant

from fishfmu.cosim.build import scenario_fish
from fishfmu.scenario.schema import Scenario, load_scenario, resolved_toml

SCENARIO_RESOURCE = "scenario.toml"

SLAVE_SCRIPT = '''"""The plant of a fishfmu scenario as an FMU (made by `fishfmu export-fmu`; needs fishfmu in the host's Python)."""
from pathlib import Path

from pythonfmu import Boolean, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real

from fishfmu.cosim.plant_fmu import SCENARIO_RESOURCE, PlantInFmu


class FishfmuPlant(Fmi2Slave):
    author = "fishfmu"
    description = "A salmon singulation line (fishfmu's Exudyn plant) with its fish"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.plant = PlantInFmu(Path(self.resources) / SCENARIO_RESOURCE)
        p = self.plant
        self.register_variable(Integer("seed", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                                       getter=lambda: p.seed, setter=p.set_seed))
        self.register_variable(Integer("fish_count", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.fixed, getter=lambda: p.fish_count,
                                       setter=p.set_fish_count))
        for c in p.conveyor_ids:
            self.register_variable(Real(f"{c}.speed", causality=Fmi2Causality.input, start=0.0, description="m/s",
                                        getter=p.getter(f"{c}.speed"), setter=p.setter(f"{c}.speed")))
        # outputs start as the line at rest (initial = exact): no photo-eye blocked, no load, no fish yet
        for name in p.output_names:
            start = p.values[name]
            if isinstance(start, bool) or isinstance(start, int):
                kind = Boolean if isinstance(start, bool) else Integer
                var = kind(name, causality=Fmi2Causality.output, variability=Fmi2Variability.discrete,
                           initial=Fmi2Initial.exact, start=start, getter=p.getter(name))
            else:
                var = Real(name, causality=Fmi2Causality.output, initial=Fmi2Initial.exact, start=start,
                           description=p.units[name], getter=p.getter(name))
            self.register_variable(var)

    def exit_initialization_mode(self):
        self.plant.start()

    def do_step(self, current_time, step_size):
        return self.plant.do_step(step_size)
'''


class PlantInFmu:
    """The plant behind the FMU's variables: built from the scenario at initialisation, stepped by doStep."""

    counts = ("fish_dropped", "fish_on_line", "fish_left", "outfeed_count")

    def __init__(self, scenario_file: Path) -> None:
        self.scenario: Scenario = load_scenario(scenario_file)
        self.seed, self.fish_count = self.scenario.run.seed, self.scenario.fish.count
        self.conveyor_ids = [c.id for c in self.scenario.line.conveyors]
        self.photoeye_ids = [p.id for p in self.scenario.line.photoeyes]
        self.output_names = ([f"{p}.blocked" for p in self.photoeye_ids]
                             + [f"{c}.{s}" for c in self.conveyor_ids for s in ("load_force", "load_mass")]
                             + list(self.counts))
        self.values: dict[str, Any] = {f"{c}.speed": 0.0 for c in self.conveyor_ids}
        self.values.update({n: (False if n.endswith(".blocked") else 0 if n in self.counts else 0.0)
                            for n in self.output_names})
        self.units = {n: "N" if n.endswith(".load_force") else "kg" for n in self.output_names
                      if n.endswith((".load_force", ".load_mass"))}
        self.plant: Plant | None = None
        self._was_blocked = False

    def getter(self, name: str):  # noqa: ANN201 - pythonfmu takes any callable
        return lambda: self.values[name]

    def setter(self, name: str):  # noqa: ANN201
        def set_(value: float) -> None:
            self.values[name] = float(value)
        return set_

    def set_seed(self, value: int) -> None:
        self.seed = int(value)

    def set_fish_count(self, value: int) -> None:
        self.fish_count = int(value)

    def start(self) -> None:
        sc = self.scenario.model_copy(deep=True)
        sc.run.seed, sc.fish.count = self.seed, self.fish_count
        self.plant = Plant(sc.line, scenario_fish(sc), sc.plant, sc.run.comm_step_s)
        self.comm_step_s = sc.run.comm_step_s
        self.outfeed = sc.kpi.outfeed_photoeye

    def do_step(self, step_size: float) -> bool:
        n = step_size / self.comm_step_s
        if n < 0.5 or abs(n - round(n)) > 1e-6:
            return False  # fmi2Error: the plant steps in whole communication steps
        speeds = {c: self.values[f"{c}.speed"] for c in self.conveyor_ids}
        for _ in range(int(round(n))):
            out = self.plant.step(speeds)
            for port, v in out.port_values().items():
                if port in self.values and not port.endswith(".speed"):
                    self.values[port] = v
            blocked = out.photoeyes[self.outfeed]
            if blocked and not self._was_blocked:
                self.values["outfeed_count"] += 1
            self._was_blocked = blocked
        status = self.plant.status
        self.values["fish_dropped"] = int(np.count_nonzero(status != WAITING))
        self.values["fish_on_line"] = int(np.count_nonzero(status == ON_LINE))
        self.values["fish_left"] = int(np.count_nonzero(status == LEFT))
        return True


def export_plant_fmu(scenario: Scenario, folder: Path) -> Path:
    """Build the plant FMU of ``scenario`` with pythonfmu into ``folder`` (a temporary one: the caller moves it);
    the scenario inside keeps what the plant needs (run, line, fish, plant, kpi), not the FMUs and wiring."""
    import tomllib

    import tomli_w
    try:
        from pythonfmu.builder import FmuBuilder
    except ImportError:
        raise InputError("export-fmu needs pythonfmu (pip install pythonfmu)") from None
    doc = tomllib.loads(resolved_toml(scenario))
    plant_only = {k: doc[k] for k in ("run", "line", "fish", "plant", "kpi") if k in doc}
    script = folder / "fishfmu_plant.py"
    script.write_text(SLAVE_SCRIPT, encoding="utf-8")
    resource = folder / "res" / SCENARIO_RESOURCE
    resource.parent.mkdir()
    resource.write_text(tomli_w.dumps(plant_only), encoding="utf-8")
    return Path(FmuBuilder.build_FMU(script, dest=folder / "built", project_files=[resource]))
