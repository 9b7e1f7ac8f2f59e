"""The served line's signal list: the information model (:mod:`fishfmu.serve.model`) as a CSV an integrator imports
into a PLC's tag table, one row per variable and method.

Columns: ``node_id`` (the expanded node id, ``nsu=urn:fishfmu;s=<name>``: the namespace by URI, as its index
may differ per server), ``browse_path`` (from Objects), ``component``, ``direction`` (``in``: a client writes it;
``out``; ``parameter``: fixed for the run; ``status``; ``method``), ``access``, ``data_type`` (OPC UA built-in
type), ``variable_type``, ``unit`` and ``unece_code`` (EngineeringUnits), ``range_low``/``range_high``
(EURange), ``states`` (a Boolean's true/false texts, an enumeration's values), ``value`` (a parameter's),
``modbus_table``, ``modbus_address`` and ``modbus_encoding`` (:mod:`fishfmu.serve.modbus_map`) and ``description``.
"""

from __future__ import annotations

import csv
import io

from fishfmu.serve.modbus_map import Address, register_map
from fishfmu.serve.model import IN, METHODS, NAMESPACE, ROOT, UNECE, InformationModel, variable_type

DATA_TYPES = {"Real": "Double", "Integer": "Int32", "Enumeration": "Int32", "Boolean": "Boolean", "String": "String"}
"""Each FMI type's OPC UA data type."""
COLUMNS = ["node_id", "browse_path", "component", "direction", "access", "data_type", "variable_type", "unit",
           "unece_code", "range_low", "range_high", "states", "value", "modbus_table", "modbus_address",
           "modbus_encoding", "description"]


def _number(x: float | None) -> str:
    return "" if x is None else repr(float(x))


def rows(model: InformationModel) -> list[dict[str, str]]:
    """One row per variable, then per method of the root object."""
    paths = {c.key: paths_of(c.key, model) for c in model.components}
    registers = register_map(model)
    out = []
    for item in model.items:
        states = (f"true={item.two_states[0]}; false={item.two_states[1]}" if item.two_states else
                  "; ".join(f"{v}={t}" for v, t in item.enumeration) if item.enumeration else "")
        out.append({"node_id": f"nsu={NAMESPACE};s={item.key}", "browse_path": f"{paths[item.component]}/{item.name}",
                    "component": item.component, "direction": item.direction,
                    "access": "read-write" if item.direction == IN else "read", "data_type": DATA_TYPES[item.type],
                    "variable_type": variable_type(item), "unit": item.unit or "",
                    "unece_code": UNECE.get(item.unit, "") if item.unit else "",
                    "range_low": _number(item.range[0]) if item.range else "",
                    "range_high": _number(item.range[1]) if item.range else "", "states": states,
                    "value": "" if item.value is None else str(item.value), "description": item.description,
                    **_modbus(registers.get(item.key))})
    for name, (arguments, text) in METHODS.items():
        out.append({**dict.fromkeys(COLUMNS, ""), "node_id": f"nsu={NAMESPACE};s={ROOT}.{name}",
                    "browse_path": f"Objects/{ROOT}/{name}", "component": ROOT, "direction": "method",
                    "access": "call", "states": arguments, "description": text})
    return out


def _modbus(a: Address | None) -> dict[str, str]:
    if a is None:
        return {"modbus_table": "", "modbus_address": "", "modbus_encoding": ""}
    return {"modbus_table": a.table, "modbus_address": str(a.address), "modbus_encoding": a.encoding}


def paths_of(key: str, model: InformationModel) -> str:
    """The browse path of the component ``key`` from Objects."""
    c = next(c for c in model.components if c.key == key)
    return f"{paths_of(c.parent, model)}/{c.name}" if c.parent else f"Objects/{c.name}"


def signal_list_csv(model: InformationModel) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows(model))
    return buffer.getvalue()
