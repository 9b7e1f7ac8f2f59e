"""The Modbus TCP server of ``fishfmu serve --modbus HOST:PORT`` (pymodbus): the register map of
:mod:`fishfmu.serve.modbus_map` served from the line's published values; writes and step requests taken as OPC UA
takes them."""

from __future__ import annotations

from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from fishfmu.serve.model import InformationModel
from fishfmu.serve.status import InvalidState
from fishfmu.serve.modbus_map import (COIL, DISCRETE_INPUT, FAILED, FIRST_VALUE, HOLDING, INPUT, RUN_STATE,
                                      STATE_CODES, STEP_REQUEST, UNIT_ID, clipped_int32, from_registers,
                                      register_map, to_registers)


class ModbusObserver:
    """The Modbus server of a served line: publishes its values, takes writes and step requests (the map and the
    rules: :mod:`fishfmu.serve.modbus_map`).  ``line`` is the :class:`fishfmu.serve.line.LineServer`."""

    def __init__(self, model: InformationModel, host: str, port: int, writable: bool, line: Any) -> None:
        self.map = register_map(model)
        self.host, self.port, self.writable, self.line = host, port, writable, line
        self.values: dict[str, Any] = {}
        self.state = "waiting"
        self._by_address = {(a.table, a.address): k for k, a in self.map.items()}
        self.server: Any = None

    def _size(self, table: str) -> int:
        used = [a.address + (1 if a.encoding == "bit" else 2) for a in self.map.values() if a.table == table]
        return max([FIRST_VALUE if table in (HOLDING, INPUT) else 1, *used])

    async def start(self) -> None:
        blocks = tuple([SimData(0, count=self._size(t), datatype=DataType.BITS if t in (COIL, DISCRETE_INPUT)
                                else DataType.REGISTERS)] for t in (COIL, DISCRETE_INPUT, HOLDING, INPUT))
        device = SimDevice(UNIT_ID, simdata=blocks, action=self._action)
        self.server = ModbusTcpServer(device, address=(self.host, self.port))
        await self.server.serve_forever(background=True)

    async def stop(self) -> None:
        if self.server is not None:
            await self.server.shutdown()

    def publish(self, values: dict[str, Any]) -> None:
        """The values the line shows now (what OPC UA publishes)."""
        self.values.update(values)
        self.state = str(values.get("fishfmu.run_state", self.state))

    def _value(self, key: str) -> Any:
        if key in self.line.external:  # as written by a client (used from the next step on)
            return self.line.space.input_value(key)
        return self.values.get(key, 0)

    def _fill(self, table: str, start: int, regs: list[int]) -> None:
        """Put the current values into ``regs`` (the block from address ``start``), as pymodbus reads them."""
        if table == INPUT:
            state = self.state.split(":")[0]
            regs[RUN_STATE - start] = STATE_CODES.get(state, STATE_CODES[FAILED])
        for key, a in self.map.items():
            if a.table != table:
                continue
            value = self._value(key)
            if a.encoding == "bit":
                word, bit = divmod(a.address, 16)
                regs[word - start] = (regs[word - start] & ~(1 << bit)) | (int(bool(value)) << bit)
            else:
                encoded = value if a.encoding == "float32" else clipped_int32(value)
                regs[a.address - start:a.address - start + 2] = to_registers(float(encoded), a.encoding)

    async def _action(self, fc: int, start: int, address: int, count: int, regs: list[int],
                      set_values: list[int] | list[bool] | None) -> Any:
        table = {1: COIL, 5: COIL, 15: COIL, 2: DISCRETE_INPUT, 3: HOLDING, 6: HOLDING, 16: HOLDING,
                 4: INPUT}.get(fc)
        if table is None:
            return ExcCodes.ILLEGAL_FUNCTION
        if set_values is None:
            self._fill(table, start, regs)
            if fc == 3:  # a read gives 0 (a write's echo, read back with its own code, gives what was written)
                regs[STEP_REQUEST - start] = 0
            return None
        if not self.writable:
            return ExcCodes.ILLEGAL_FUNCTION
        if table == HOLDING and address == STEP_REQUEST:
            return await self._step(set_values)
        return await self._write(table, address, list(set_values))

    async def _step(self, set_values: list[Any]) -> Any:
        n = int(set_values[0])
        if len(set_values) != 1 or not 1 <= n <= 65535:
            return ExcCodes.ILLEGAL_VALUE
        if self.line.realtime is not None:
            return ExcCodes.ILLEGAL_FUNCTION  # the wall clock steps the line
        try:
            await self.line.step(n)
        except InvalidState:  # waiting for start(), or paused
            return ExcCodes.DEVICE_BUSY
        return None

    async def _write(self, table: str, address: int, values: list[Any]) -> Any:
        """Inputs written from ``address`` on: each decoded and checked as an OPC UA write is, then given to the
        address space (the line takes it before its next step)."""
        writes = []
        i = 0
        while i < len(values):
            key = self._by_address.get((table, address + i))
            if key is None or key not in self.line.external:
                return ExcCodes.ILLEGAL_ADDRESS
            a = self.map[key]
            if a.encoding == "bit":
                writes.append((key, bool(values[i])))
                i += 1
                continue
            if i + 1 >= len(values):
                return ExcCodes.ILLEGAL_ADDRESS  # half a 32-bit value
            writes.append((key, from_registers([int(values[i]), int(values[i + 1])], a.encoding)))
            i += 2
        for key, value in writes:
            if not await self.line.space.write_input(key, value):
                return ExcCodes.ILLEGAL_VALUE
        return None
