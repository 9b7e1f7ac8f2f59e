"""The line in Exudyn: the plant's parameters, the joints' laws, the Exudyn system, the
:class:`~plant.sim.plant.Plant` stepped from outside and the :class:`~plant.sim.state.PlantState` it
publishes after each step (all that readers outside the plant read), its ports declared once
(:mod:`plant.sim.ports`), its sensors, health checks, recording, and the plant run alone."""
