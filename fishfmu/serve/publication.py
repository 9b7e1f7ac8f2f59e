"""What ``fishfmu serve`` shows of its line, and when: a step observer of the line, published after each batch of
steps to every way the line is served (the OPC UA address space with its status nodes, the Modbus server, the live
view).

:class:`Publication` is attached to every co-simulation the served line builds (its start and each reset), in one
place (``LineServer._start_cosim``), after the observers every way of stepping attaches (the energy watch, the fish
counts, the recording: :mod:`plant.sim.observers`).  Its ``after_step`` runs in the line's worker thread, in every
step, and keeps what only a step sees: each belt's travel, step by step (the live view's moving stripes).  Its
``publish`` runs in the server's event loop **after a batch of steps** (a lockstep ``step(n)``, every
:data:`~fishfmu.serve.line.PUBLISH_EVERY_S` of a long one and at its end; each step in real time; every change of
state) and gives every server the same values (:func:`fishfmu.serve.address_space.shown_values`).

Why after a batch and not in every step: the address space, the Modbus server and the live view live in the asyncio
event loop, the steps in the worker thread (so that the server answers clients while the line steps).  Publishing
from within a step would hand the event loop work in every step and make the stepping thread wait for it (a
``step(1000)`` would wait a thousand times), while a client sees only the values of the moments it reads anyway: in
lockstep it reads after its ``step(n)`` returns, in real time a batch is one step.  Pacing (when a step is due against the wall
clock) is no observer either: as libcosim's real-time timer belongs to its execution, it decides when the next step
starts (:mod:`fishfmu.serve.pacing`), before there is a step to observe.
"""

from __future__ import annotations

import asyncio
from typing import Any

import numpy as np

from plant.sim.observers import StepInputs
from plant.sim.state import PlantOutputs, PlantState

from fishfmu.serve.address_space import AddressSpace
from fishfmu.serve.options import modbus_host_port


class Publication:
    """The served line's step observer and what it publishes after a batch of steps (see the module docstring)."""

    def __init__(self, space: AddressSpace, conveyor_ids: list[str]) -> None:
        self.space, self.conveyor_ids = space, conveyor_ids
        self.modbus: Any = None
        """The Modbus server (:class:`fishfmu.serve.modbus.ModbusObserver`) with ``--modbus``."""
        self.live: Any = None
        """The live view (:class:`fishfmu.serve.live.LiveView`) with ``--live``."""
        self.values: dict[str, Any] = {}
        """What was published last."""
        self.travel_m = np.zeros(len(conveyor_ids))
        """Each belt's travel since the run (re)started, summed step by step."""

    def new_run(self) -> None:
        """A co-simulation was built (the start, a reset): its steps start from rest."""
        self.travel_m = np.zeros(len(self.conveyor_ids))

    def after_step(self, state: PlantState, outputs: PlantOutputs, inputs: StepInputs, dt_s: float) -> None:
        speeds = outputs.belt_speed_mps
        self.travel_m = self.travel_m + dt_s * np.array([speeds[c] for c in self.conveyor_ids])

    async def publish(self, values: dict[str, Any], cosim: Any) -> None:
        """After a batch of steps (the line not stepping): ``values`` to the address space, the Modbus server and
        the live view (a frame of ``cosim`` when one is due)."""
        await self.space.publish(values)
        if self.modbus is not None:
            self.modbus.publish(values)
        self.values = values
        if self.live is not None and cosim is not None and self.live.due():
            self.live.capture(cosim, values, self.travel_m)

    async def start_modbus(self, at: str, writable: bool, line: Any) -> None:
        """The Modbus TCP server beside OPC UA at ``at`` (:mod:`fishfmu.serve.modbus`; pymodbus imported only for it)
        with every value published so far, not only the next changes."""
        from fishfmu.serve.modbus import ModbusObserver  # pymodbus: only when --modbus is given
        self.modbus = ModbusObserver(self.space.model, *modbus_host_port(at), writable, line)
        await self.modbus.start()
        self.modbus.publish(dict(self.space.published))

    async def start_live(self, at: str, line: Any, lock: asyncio.Lock) -> None:
        """The live view at ``at`` (:mod:`fishfmu.serve.live`; tornado imported only for it), with the ``line``'s
        latest step taken, holding ``lock``, when no publication took it (the end of a step(n), a pause): never
        waiting for the line."""
        from fishfmu.serve.live import LiveView  # tornado: only when --live is given
        self.live = LiveView(*modbus_host_port(at), line.scenario.line, line.scenario.run.name)
        self.live.capture(line.cosim, self.values, self.travel_m)

        async def catch_up() -> None:
            async with lock:
                if line.cosim is not None:
                    self.live.capture(line.cosim, self.values, self.travel_m)
        await self.live.start(lambda: self.live.stale(line.cosim, self.values) and not lock.locked(), catch_up)

    async def stop(self) -> None:
        if self.modbus is not None:
            await self.modbus.stop()
        if self.live is not None:
            await self.live.stop()
