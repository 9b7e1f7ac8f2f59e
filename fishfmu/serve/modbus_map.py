"""The served line's Modbus register map (the server: :mod:`fishfmu.serve.modbus`); the line as a Modbus TCP server too (``fishfmu serve --modbus HOST:PORT``, pymodbus), beside OPC UA: the
same signals from the same information model (:mod:`fishfmu.serve.model`), published on the same steps.

The register map (:func:`register_map`, also in the signal list's ``modbus_*`` columns), unit id 1:

- **coils** (read 1, write 5/15): the Boolean inputs a client writes (a device's ``command``), from address 0;
- **discrete inputs** (read 2): every other Boolean (photo-eyes, limit switches, camera flags), from 0;
- **holding registers** (read 3, write 6/16): register 0 is the **step request** (lockstep: write n, 1 to 65535, and
  the reply comes once the line has made n communication steps, as OPC UA's ``step(n)``; a read gives 0); from
  register 2 the Real and Integer inputs a client writes;
- **input registers** (read 4): register 0 the run's state (0 waiting, 1 running, 2 paused, 3 finished, 4 stopped,
  5 failed), from register 2 the status (``time_s``, ``lag_s``, ...), the KPIs and every other Real and Integer.

A Real is an IEEE 754 float32 and an Integer an int32, each in two registers, **high word first** (big-endian
words and bytes, "ABCD"); a float32 carries about 7 significant digits of the line's doubles.  A value written
is used from the next communication step on, as an OPC UA write is, and checked the same way (its type and
declared range: ILLEGAL_VALUE otherwise); a write of half a 32-bit pair or to an output is ILLEGAL_ADDRESS.
Modbus has no users: writes are refused (ILLEGAL_FUNCTION) unless the server was started with
``--allow-anonymous-write``, and it listens on the loopback interface unless ``--allow-remote``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

from fishfmu.serve.model import IN, PARAMETER, InformationModel
from fishfmu.serve.status import FAILED

UNIT_ID = 1
STEP_REQUEST = 0
"""Holding register 0: the lockstep step request."""
RUN_STATE = 0
"""Input register 0: the run's state as a code."""
STATE_CODES = {"waiting": 0, "running": 1, "paused": 2, "finished": 3, "stopped": 4, FAILED: 5}
FIRST_VALUE = 2
"""The first register of a 32-bit value in the holding and input registers (0-1 are the control registers)."""
COIL, DISCRETE_INPUT, HOLDING, INPUT = "coil", "discrete_input", "holding_register", "input_register"


@dataclass(frozen=True)
class Address:
    table: str
    address: int
    encoding: str
    """``bit``, ``float32`` or ``int32`` (two registers, high word first)."""


def register_map(model: InformationModel) -> dict[str, Address]:
    """Each served item's Modbus address (parameters and strings are not mapped: OPC UA and the signal list give
    them)."""
    out: dict[str, Address] = {}
    next_of = {COIL: 0, DISCRETE_INPUT: 0, HOLDING: FIRST_VALUE, INPUT: FIRST_VALUE}
    for item in model.items:
        if item.direction == PARAMETER or item.type == "String":
            continue
        if item.type == "Boolean":
            table, size, encoding = (COIL if item.direction == IN else DISCRETE_INPUT), 1, "bit"
        else:
            table, size = (HOLDING if item.direction == IN else INPUT), 2
            encoding = "float32" if item.type == "Real" else "int32"
        out[item.key] = Address(table, next_of[table], encoding)
        next_of[table] += size
    return out


def to_registers(value: float, encoding: str) -> list[int]:
    """A value as two registers, high word first."""
    raw = struct.pack(">f", value) if encoding == "float32" else struct.pack(">i", int(value))
    return [int.from_bytes(raw[:2], "big"), int.from_bytes(raw[2:], "big")]


def from_registers(words: list[int], encoding: str) -> float | int:
    raw = words[0].to_bytes(2, "big") + words[1].to_bytes(2, "big")
    return struct.unpack(">f", raw)[0] if encoding == "float32" else struct.unpack(">i", raw)[0]


def clipped_int32(value: Any) -> int:
    return max(-2**31, min(2**31 - 1, int(value)))
