"""The physical singulation line: fish, conveyors, guides and photo-eyes simulated in Exudyn.

Knows nothing of FMI: its inputs are belt speeds, its outputs sensor readings and fish poses.
Three parts, each a sub-package, imported in this order (a part imports only those before it):

- :mod:`plant.fish`: the fish: the paper's salmon data, a fish as five bodies with contact spheres
  and outlines, the batch of a run, the candidate effects beyond the paper's model (extensions);
- :mod:`plant.contract`: the measured-data and KPI contract (docs/measured-data.md, docs/kpis.md): the
  line as a dataset or a scenario describes it, the format and its plausibility bounds, passages and KPIs;
  measured and simulated runs go through it alike;
- :mod:`plant.sim`: the line in Exudyn: the plant's parameters, the joints' laws, the Exudyn system,
  the :class:`~plant.sim.plant.Plant` stepped from outside and the :class:`~plant.sim.state.PlantState`
  it publishes, its ports, sensors, health checks, recording and the plant run alone.

Shared by all three: :mod:`plant.errors` (the kinds of failure, as exceptions) and :mod:`plant.validation`
(schema checks with messages a person can act on).
"""
