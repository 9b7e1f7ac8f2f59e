"""The served line's address space: what an OPC UA client of ``fishfmu serve`` sees and may write.

The nodes of the information model (:mod:`fishfmu.serve.model`) in the namespace ``urn:fishfmu``: the object
``fishfmu`` under Objects, an object per component under it, each signal a variable (node id ``s=<its name>``) of
the type OPC UA clients look for: a Real an AnalogItemType (with an ``EURange``) or a BaseAnalogType (without),
its ``EngineeringUnits`` (UNECE code) and ``EURange`` properties in namespace 0 where Part 8 puts them; a Boolean
a TwoStateDiscreteType (``TrueState``/``FalseState``); a code a MultiStateValueDiscreteType (``EnumValues``,
``ValueAsText``).  A component's parameters are its properties.  ``fishfmu.time_s``, ``fishfmu.run_state`` and the
fish counts are on the root object, with the methods ``step(n)``, ``stop()`` and ``reset()``, whose arguments are
checked here (what they do is the line's, :class:`fishfmu.serve.line.LineServer`).  Only the external inputs are
writable, and a write one cannot take is refused item by item with its status before asyncua stores it.
"""

from __future__ import annotations

import math
from datetime import datetime, timezone
from collections.abc import Awaitable, Callable
from typing import Any

from asyncua import ua
from asyncua.common.callback import CallbackType

from fishfmu.cosim.build import CheckedScenario
from fishfmu.cosim.master import CoSimulation
from fishfmu.serve.access import UserRights
from fishfmu.serve.model import (NAMESPACE, PARAMETER, ROOT, STATUS_ITEMS, UNECE, Component, InformationModel, Item,
                                 information_model, variable_type)
from fishfmu.serve.options import realtime_problem
from fishfmu.serve.status import InvalidState

UNITS_NAMESPACE = "http://www.opcfoundation.org/UA/units/un/cefact"
_FISH_COUNTS = ("fish_waiting", "fish_on_line", "fish_left", "fish_rejected")
"""The fish counts served (``fishfmu.<name>``), as the run's step observer counts them
(:class:`plant.sim.observers.FishCounts`)."""

_VARIANT_TYPES = {"Real": (ua.VariantType.Double, 0.0), "Integer": (ua.VariantType.Int32, 0),
                  "Enumeration": (ua.VariantType.Int32, 0), "Boolean": (ua.VariantType.Boolean, False),
                  "String": (ua.VariantType.String, "")}
"""Each FMI type's OPC UA data type and the value a node holds before the first publication."""
_INTEGER_TYPES = {ua.VariantType.SByte, ua.VariantType.Byte, ua.VariantType.Int16, ua.VariantType.UInt16,
                  ua.VariantType.Int32, ua.VariantType.UInt32, ua.VariantType.Int64, ua.VariantType.UInt64}


def _unit_id(code: str) -> int:
    """The UnitId of a UNECE code as OPC UA Part 8 defines it (each character's code, big-endian)."""
    out = 0
    for ch in code.rjust(3, "\0")[-3:]:
        out = (out << 8) | ord(ch)
    return out


_NOTHING = object()
"""No value published yet."""


def _same(a: Any, b: Any) -> bool:
    """``a == b``, NaN equal to NaN (an undefined KPI stays NaN without being written again)."""
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def _variant(value: Any, vtype: Any) -> Any:
    """``value`` as an OPC UA Variant of its node's type (a Real signal holding an int is still a Double)."""
    cast = {ua.VariantType.Double: float, ua.VariantType.Int32: int, ua.VariantType.Boolean: bool,
            ua.VariantType.String: str}[vtype]
    return ua.Variant(cast(value), vtype)



_DATA_TYPES = {ua.VariantType.Double: ua.ObjectIds.Double, ua.VariantType.Int32: ua.ObjectIds.Int32,
               ua.VariantType.Boolean: ua.ObjectIds.Boolean, ua.VariantType.String: ua.ObjectIds.String}


def _eu_information(unit: str) -> Any:
    code = UNECE.get(unit)
    return ua.EUInformation(NamespaceUri=UNITS_NAMESPACE, UnitId=_unit_id(code) if code else -1,
                            DisplayName=ua.LocalizedText(unit), Description=ua.LocalizedText(unit))


def _variable(idx: int, key: str, parent: str | ua.NodeId, name: str, value: ua.Variant, data_type: int,
              type_def: int, description: str, *, prop: bool = False, writable: bool = False,
              name_ns: int | None = None) -> Any:
    """The AddNodesItem of a variable (or a property, ``prop``) ``key`` under ``parent``."""
    node = ua.AddNodesItem()
    node.RequestedNewNodeId = ua.NodeId(key, idx)
    node.BrowseName = ua.QualifiedName(name, idx if name_ns is None else name_ns)
    node.NodeClass = ua.NodeClass.Variable
    node.ParentNodeId = parent if isinstance(parent, ua.NodeId) else ua.NodeId(parent, idx)
    node.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasProperty if prop else ua.ObjectIds.HasComponent)
    node.TypeDefinition = ua.NodeId(type_def)
    attrs = ua.VariableAttributes()
    attrs.Description, attrs.DisplayName = ua.LocalizedText(description), ua.LocalizedText(name)
    attrs.DataType = ua.NodeId(data_type)
    attrs.Value = value
    attrs.ValueRank = ua.ValueRank.OneDimension if isinstance(value.Value, list) else ua.ValueRank.Scalar
    attrs.ArrayDimensions = [0] if isinstance(value.Value, list) else None
    attrs.WriteMask = attrs.UserWriteMask = 0
    access = ua.AccessLevel.CurrentRead.mask | (ua.AccessLevel.CurrentWrite.mask if writable else 0)
    attrs.AccessLevel = attrs.UserAccessLevel = access
    attrs.Historizing = False
    node.NodeAttributes = attrs
    return node


def _object(idx: int, c: Component, parent: ua.NodeId) -> Any:
    node = ua.AddNodesItem()
    node.RequestedNewNodeId = ua.NodeId(c.key, idx)
    node.BrowseName = ua.QualifiedName(c.name, idx)
    node.NodeClass = ua.NodeClass.Object
    node.ParentNodeId = parent
    node.ReferenceTypeId = ua.NodeId(ua.ObjectIds.Organizes if c.key == ROOT else ua.ObjectIds.HasComponent)
    node.TypeDefinition = ua.NodeId(ua.ObjectIds.BaseObjectType)
    attrs = ua.ObjectAttributes()
    attrs.Description, attrs.DisplayName = ua.LocalizedText(c.description), ua.LocalizedText(c.name)
    attrs.EventNotifier = 1 if c.key == ROOT else 0  # the root object sends the run's events
    attrs.WriteMask = attrs.UserWriteMask = 0
    node.NodeAttributes = attrs
    return node


def node_items(idx: int, model: InformationModel, external: list[str]) -> list[Any]:
    """The AddNodesItems of the whole model, parents before children."""
    objects = ua.NodeId(ua.ObjectIds.ObjectsFolder)
    nodes = [_object(idx, c, objects if c.key == ROOT else ua.NodeId(c.parent, idx)) for c in model.components]
    for item in model.items:
        vtype, initial = _VARIANT_TYPES[item.type]
        value = ua.Variant(item.value if item.value is not None else initial, vtype)
        nodes.append(_variable(idx, item.key, item.component, item.name, value, _DATA_TYPES[vtype],
                               getattr(ua.ObjectIds, variable_type(item)), item.description, prop=item.direction == PARAMETER,
                               writable=item.key in external))
        props: list[tuple[str, ua.Variant, int]] = []
        if item.unit:
            props.append(("EngineeringUnits", ua.Variant(_eu_information(item.unit)), ua.ObjectIds.EUInformation))
        if item.range is not None and item.type == "Real":  # Part 8: an analog item's
            rng = ua.Range(Low=float(item.range[0]), High=float(item.range[1]))
            props.append(("EURange", ua.Variant(rng), ua.ObjectIds.Range))
        if item.two_states:
            props += [(state, ua.Variant(ua.LocalizedText(text)), ua.ObjectIds.LocalizedText)
                      for state, text in zip(("TrueState", "FalseState"), item.two_states)]
        if item.enumeration:
            values = [ua.EnumValueType(Value=v, DisplayName=ua.LocalizedText(t), Description=ua.LocalizedText(t))
                      for v, t in item.enumeration]
            props.append(("EnumValues", ua.Variant(values), ua.ObjectIds.EnumValueType))
            props.append(("ValueAsText", ua.Variant(ua.LocalizedText(_text_of(item, initial))),
                          ua.ObjectIds.LocalizedText))
        if item.direction != PARAMETER:
            nodes += [_variable(idx, f"{item.key}.{name}", ua.NodeId(item.key, idx), name, value, dtype,
                                ua.ObjectIds.PropertyType, name, prop=True, name_ns=0)
                      for name, value, dtype in props]
    return nodes


def _text_of(item: Item, value: Any) -> str:
    """An enumeration's text for ``value``."""
    return dict(item.enumeration or ()).get(int(value), str(value))


def shown_values(c: CoSimulation | None, state: str, names: list[str], served: list[str],
                 status: dict[str, Any]) -> dict[str, Any]:
    """What the address space shows of the co-simulation ``c`` (None: not built) in the run state ``state``, with
    the run's ``status`` values (its clock, its KPIs) by node id."""
    values: dict[str, Any] = {"fishfmu.time_s": c.t_s if c is not None else 0.0, "fishfmu.run_state": state,
                              **status}
    if c is not None:
        # the last recorded row (inputs as sent, outputs as they are); before the first step the start values;
        # the plant's outputs not recorded as they are now
        row = c.signals[-1][1:] if c.signals else [c.values.get(k, c.constants.get(k)) for k in names]
        values.update(zip(names, row))
        values.update((k, c.values.get(k)) for k in served[len(names):])
        if c.steps:
            values.update((f"fishfmu.{k}", c.fish_counts.values[k]) for k in _FISH_COUNTS)
        else:  # before the first step no observer has counted: the whole batch waits
            values.update((f"fishfmu.{k}", len(c.plant.state.status) if k == "fish_waiting" else 0)
                          for k in _FISH_COUNTS)
    return values


def _one_argument(args: tuple, types: set[Any], check: Callable[[Any], bool]) -> Any:
    """The value of a method's one argument, or the refusal of a call without it, with more, or with a value of
    another type or one ``check`` refuses."""
    if not args:
        return refused(ua.StatusCodes.BadArgumentsMissing)
    if len(args) > 1:
        return refused(ua.StatusCodes.BadTooManyArguments)
    n = args[0]
    if (not isinstance(n, ua.Variant) or n.VariantType not in types or n.is_array or isinstance(n.Value, bool)
            or not isinstance(n.Value, (int, float))):
        return refused(ua.StatusCodes.BadInvalidArgument, [ua.StatusCodes.BadTypeMismatch])
    if not check(n.Value):
        return refused(ua.StatusCodes.BadInvalidArgument, [ua.StatusCodes.BadOutOfRange])
    return n.Value


def _argument(name: str, type_id: int, text: str) -> Any:
    return ua.Argument(Name=name, DataType=ua.NodeId(type_id), ValueRank=-1, Description=ua.LocalizedText(text))


async def _add_methods(folder: Any, idx: int, lockstep: bool, line: Any) -> None:
    """The root object's methods (see :data:`fishfmu.serve.model.METHODS`), each calling ``line``'s coroutine of
    the same name; one the run's state does not allow (:class:`InvalidState`) gets BadInvalidState."""

    def method(fn: Callable[..., Awaitable[Any]], allowed: bool = True) -> Callable[..., Awaitable[Any]]:
        async def call(parent: Any, *args: Any) -> Any:
            if not allowed:
                return refused(ua.StatusCodes.BadInvalidState)
            try:
                return await fn(*args)
            except InvalidState:
                return refused(ua.StatusCodes.BadInvalidState)
        return call

    def no_arguments(fn: Callable[[], Awaitable[Any]], out: bool = False) -> Callable[..., Awaitable[Any]]:
        async def call(*args: Any) -> Any:
            if args:
                return refused(ua.StatusCodes.BadTooManyArguments)
            value = await fn()
            return [ua.Variant(value, ua.VariantType.Double)] if out else []
        return call

    async def step(*args: Any) -> Any:
        n = _one_argument(args, _INTEGER_TYPES, lambda v: isinstance(v, int) and v >= 0)
        return n if isinstance(n, ua.CallMethodResult) else [ua.Variant(await line.step(n), ua.VariantType.Double)]

    async def reset(*args: Any) -> Any:
        seed = _one_argument(args, _INTEGER_TYPES, lambda v: isinstance(v, int) and 0 <= v < 2**32) if args else None
        if isinstance(seed, ua.CallMethodResult):
            return seed
        return [ua.Variant(await line.reset(seed), ua.VariantType.Double)]

    async def set_speed(*args: Any) -> Any:
        factor = _one_argument(args, {ua.VariantType.Double, ua.VariantType.Float, *_INTEGER_TYPES},
                               lambda v: realtime_problem(float(v)) is None)
        if isinstance(factor, ua.CallMethodResult):
            return factor
        await line.set_speed(float(factor))
        return []

    t_out = _argument("time_s", ua.ObjectIds.Double, "simulated time afterwards, s")
    table = {"step": (method(step, lockstep), [_argument("n", ua.ObjectIds.Int32, "communication steps to advance "
                                                                                   "(0 or more)")], [t_out]),
             "start": (method(no_arguments(line.start)), [], []),
             "pause": (method(no_arguments(line.pause)), [], []),
             "resume": (method(no_arguments(line.resume)), [], []),
             "stop": (method(no_arguments(line.stop)), [], []),
             "reset": (method(reset), [_argument("seed", ua.ObjectIds.UInt32, "optional: the seed of the run to "
                                                                                "start (default: the scenario's)")],
                       [t_out]),
             "set_speed": (method(set_speed, not lockstep),
                           [_argument("factor", ua.ObjectIds.Double, "real-time factor, 0.001 to 1000")], [])}
    for name, (fn, inputs, outputs) in table.items():
        await folder.add_method(ua.NodeId(f"{ROOT}.{name}", idx), ua.QualifiedName(name, idx), fn, inputs, outputs)


def refused(code: Any, per_argument: list[Any] | None = None) -> Any:
    """A method call's answer when it is refused: ``code``, and a status per argument."""
    return ua.CallMethodResult(StatusCode=ua.StatusCode(code),
                               InputArgumentResults=[ua.StatusCode(c) for c in per_argument or []])


class AddressSpace:
    """The line's nodes in a server (see the module docstring); :meth:`build` makes them."""

    def __init__(self, checked: CheckedScenario, served: list[str], external: list[str]) -> None:
        self.checked, self.served, self.external = checked, served, external
        self.model = information_model(checked, served, STATUS_ITEMS)
        self.nodes: dict[str, Any] = {}
        self.as_text: dict[str, tuple[Any, Item]] = {}
        """An enumeration's ValueAsText node, by its variable."""
        self.types: dict[str, Any] = {}
        self.ranges: dict[str, tuple[float, float] | None] = {}
        self.last_written: dict[str, Any] = {}
        """Each external input's value as last taken by the line (or its start value)."""
        self.published: dict[str, Any] = {}
        """Each other node's value as last published (see :meth:`publish`)."""
        self.server: Any = None

    async def build(self, server: Any, lockstep: bool, line: Any) -> None:
        """The model's objects, variables and methods in ``server``; each method calls the coroutine of the same
        name of ``line`` (:class:`fishfmu.serve.line.LineServer`) with its arguments checked; ``step`` only in
        ``lockstep``, ``set_speed`` only in real time."""
        self.server = server
        idx = await server.register_namespace(NAMESPACE)
        results = await server.iserver.isession.add_nodes(node_items(idx, self.model, self.external))
        for r in results:
            r.StatusCode.check()
        folder = server.get_node(ua.NodeId(ROOT, idx))
        for item in self.model.items:
            if item.direction == PARAMETER:
                continue
            self.nodes[item.key] = server.get_node(ua.NodeId(item.key, idx))
            self.types[item.key] = _VARIANT_TYPES[item.type][0]
            self.ranges[item.key] = item.range
            if item.enumeration:
                self.as_text[item.key] = (server.get_node(ua.NodeId(f"{item.key}.ValueAsText", idx)), item)
        await self.restart_inputs()
        self._guard_writes(server)

        await _add_methods(folder, idx, lockstep, line)
        server.subscribe_server_callback(CallbackType.PostRead, UserRights(idx))  # each session's own rights
        self.event = await server.get_event_generator(ua.ObjectIds.BaseEventType, folder.nodeid)

    async def announce(self, state: str) -> None:
        """An event from the root object: the run's state is now ``state``."""
        self.event.event.Severity = 700 if state.startswith("failed") else 300
        await self.event.trigger(message=f"run_state: {state}")

    async def restart_inputs(self) -> None:
        """Every external input back at its start value (the scenario's), as the line takes it."""
        for key in self.external:
            start = self.checked.wiring.constants[key]
            await self.nodes[key].write_value(_variant(start, self.types[key]))
            self.last_written[key] = start

    def input_value(self, key: str) -> Any:
        """The external input ``key`` as clients last wrote it (used from the next step on)."""
        return self.server.iserver.aspace.read_attribute_value(self.nodes[key].nodeid,
                                                               ua.AttributeIds.Value).Value.Value

    async def write_input(self, key: str, value: Any) -> bool:
        """Write the external input ``key`` as a client's write would (another protocol's, e.g. Modbus): False,
        and nothing written, when an OPC UA write of it would be refused."""
        data = ua.DataValue(_variant(value, self.types[key]))
        if isinstance(value, float) and self.types[key] != ua.VariantType.Double:
            return False
        if self.write_refusal(key, data) is not None:
            return False
        await self.server.write_attribute_value(self.nodes[key].nodeid, data)
        return True

    def changed_inputs(self) -> list[tuple[str, Any]]:
        """The external inputs a client changed since the last call, with their values (read from the address
        space directly: a plain read, safe from the line's worker thread)."""
        changed = []
        for key in self.external:
            value = self.server.iserver.aspace.read_attribute_value(self.nodes[key].nodeid,
                                                                    ua.AttributeIds.Value).Value.Value
            if value != self.last_written.get(key):
                self.last_written[key] = value
                changed.append((key, value))
        return changed

    async def publish(self, values: dict[str, Any]) -> None:
        """Write ``values`` (see :func:`shown_values`) into their nodes; an external input is the clients'.

        Only the values that changed since they were last published are written, straight into the address
        space (the server's own write, which still notifies subscriptions): through a node's write service
        every value of every step cost about 1 ms a step in the event loop, a fifth of a served step, which
        made steps late while a PLC's writes waited for it.  A node's timestamp is that of its last change."""
        now = datetime.now(timezone.utc)
        for name, value in values.items():
            if name in self.external or value is None or _same(self.published.get(name, _NOTHING), value):
                continue
            self.published[name] = value
            await self.server.write_attribute_value(
                self.nodes[name].nodeid, ua.DataValue(_variant(value, self.types[name]), SourceTimestamp=now,
                                                      ServerTimestamp=now))
            if name in self.as_text:
                node, item = self.as_text[name]
                await self.server.write_attribute_value(node.nodeid, ua.DataValue(
                    ua.Variant(ua.LocalizedText(_text_of(item, value))), SourceTimestamp=now, ServerTimestamp=now))

    def write_refusal(self, key: str, value: Any) -> Any:
        """The status a write of the DataValue ``value`` to the external input ``key`` is refused with, or None.
        asyncua checks a written Variant's type, not its shape nor its value."""
        if value.StatusCode is not None and not value.StatusCode.is_good():
            return ua.StatusCodes.BadWriteNotSupported  # asyncua would store a null the line cannot use
        v = value.Value
        if v is None or v.VariantType != self.types[key] or v.is_array or v.Dimensions:
            return ua.StatusCodes.BadTypeMismatch
        x = v.Value
        if isinstance(x, float) and not math.isfinite(x):
            return ua.StatusCodes.BadOutOfRange
        rng = self.ranges[key]
        if rng is not None and isinstance(x, (int, float)) and not rng[0] <= x <= rng[1]:
            return ua.StatusCodes.BadOutOfRange
        return None

    def _guard_writes(self, server: Any) -> None:
        """Refuse, item by item, the writes an external input cannot take (see :meth:`write_refusal`), before
        asyncua's attribute service stores them."""
        service = server.iserver.attribute_service
        write = service.write
        inputs = {self.nodes[k].nodeid: k for k in self.external}

        async def guarded(params: Any, *args: Any, **kwargs: Any) -> list[Any]:
            refusals: dict[int, Any] = {}
            for i, item in enumerate(params.NodesToWrite):
                key = inputs.get(item.NodeId)
                if key is None:
                    continue
                if item.AttributeId == ua.AttributeIds.Value and item.IndexRange:
                    refusals[i] = ua.StatusCodes.BadWriteNotSupported
                elif item.AttributeId == ua.AttributeIds.Value:
                    code = self.write_refusal(key, item.Value)
                    if code is not None:
                        refusals[i] = code
            if not refusals:
                return await write(params, *args, **kwargs)
            rest = [item for i, item in enumerate(params.NodesToWrite) if i not in refusals]
            done = iter(await write(ua.WriteParameters(NodesToWrite=rest), *args, **kwargs) if rest else [])
            return [ua.StatusCode(refusals[i]) if i in refusals else next(done)
                    for i in range(len(params.NodesToWrite))]

        service.write = guarded
