"""``fishfmu serve``: the line as an OPC UA server, for a PLC to commission against (asyncua).

Address space: a folder ``fishfmu`` under Objects, in the namespace ``urn:fishfmu``, with one variable per
signal of the run (every connected variable, constant input, external input and ``[record]``ed variable,
named as the scenario names it: ``plant.pe_c4.blocked``, ``drive_c1.belt_speed``, node id ``s=<that name>``),
each with its OPC UA data type (Double, Int32/Int64, Boolean, String) and, where the FMU or plant port gives a
unit, an ``EngineeringUnits`` property (and ``EURange`` from a declared min/max); ``fishfmu.time_s`` and
``fishfmu.run_state`` (``running``, ``finished``, ``stopped``, ``failed: ...``); methods ``step(n)``,
``stop()`` and ``reset()``.  Only the inputs of ``[opcua] inputs`` are writable: a value written by a client
is used from the next communication step on, as a PLC's outputs are on its next scan.

Two ways to advance:

* **lockstep**: the line moves only when a client calls ``step(n)`` (n communication steps; returns the new
  time): deterministic tests of PLC logic, the same results as a run of the same scenario and seed when the
  client writes what the controller FMU would have;
* **real time** (``--realtime [FACTOR]``): step k is due at ``start + k dt / FACTOR`` on the monotonic clock;
  the lateness of each step's start against its due time is measured, and a step starting more than one
  communication step late counts as an overrun.  p50/p99/max lateness and the overrun count go to
  ``run_info.json`` (``served``) and the console; when the line cannot keep up (the median lateness grows
  beyond a step) the console says so, with the time and the number of fish on the line.

The run ends at ``run.duration_s`` (real time), or when a client calls ``stop()``, or on Ctrl-C/SIGTERM; it is
then written like any run (KPIs, signals with every value clients wrote, the run in the measured-data format).

Security: the endpoint must be on the loopback interface unless ``allow_remote`` is given.  With ``user`` (the
password from the environment variable ``FISHFMU_OPCUA_PASSWORD``, never a command-line argument) anonymous
sessions are refused and only that user may connect.  Without certificates the connection is unencrypted (the
NoSecurity policy: a password crosses the network in plain text).  With ``certificates`` (the server's certificate
and private key, and a folder of trusted client certificates) the server offers only Basic256Sha256 with
SignAndEncrypt and accepts only clients whose certificate is in that folder.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import numpy as np

from plant.errors import InputError, SimulationError
from plant.plant import ON_LINE
from plant.simulate import ClearWatch

from fishfmu.cosim.build import CheckedScenario, build, scenario_fish
from fishfmu.cosim.master import CoSimulation
from fishfmu.cosim.results import RunResult
from fishfmu.cosim.runner import CLEAR_MARGIN_S, collect
from fishfmu.scenario.wiring import PLANT, PLANT_UNITS, signal_names

NAMESPACE = "urn:fishfmu"
FOLDER = "fishfmu"
DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840"
PASSWORD_ENV = "FISHFMU_OPCUA_PASSWORD"

# UNECE Recommendation 20 codes for the units the line uses (OPC UA Part 8, EUInformation.UnitId)
_UNECE = {"m": "MTR", "m/s": "MTS", "s": "SEC", "N": "NEW", "kg": "KGM", "rpm": "RPM", "1/min": "RPM",
          "rad/s": "2A", "A": "AMP", "V": "VLT", "W": "WTT", "Hz": "HTZ", "K": "KEL", "degC": "CEL"}


def _unit_id(code: str) -> int:
    """The UnitId of a UNECE code as OPC UA Part 8 defines it (each character's code, big-endian)."""
    out = 0
    for ch in code.rjust(3, "\0")[-3:]:
        out = (out << 8) | ord(ch)
    return out


def endpoint_problem(endpoint: str, allow_remote: bool) -> str | None:
    """Why the server must not listen at ``endpoint``, or None."""
    url = urlparse(endpoint)
    if url.scheme != "opc.tcp" or not url.hostname or url.port is None:
        return f"'{endpoint}' is not an endpoint of the form opc.tcp://HOST:PORT"
    if allow_remote:
        return None
    host = url.hostname
    try:
        local = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        local = False
    if not local:
        return (f"'{host}' is not the loopback interface: other hosts could write the line's inputs without a user "
                "check; give --allow-remote to open it on purpose")
    return None


@dataclass
class Pacing:
    """Lateness of each step's start against its due time (real time), s."""

    factor: float
    comm_step_s: float
    lateness_s: list[float] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        late = np.asarray(self.lateness_s) if self.lateness_s else np.zeros(1)
        return {"factor": self.factor, "steps": len(self.lateness_s),
                "lateness_p50_s": round(float(np.percentile(late, 50)), 6),
                "lateness_p99_s": round(float(np.percentile(late, 99)), 6),
                "lateness_max_s": round(float(late.max()), 6),
                "overruns": int((late > self.comm_step_s / self.factor).sum()),
                "overrun_rule": "a step that starts more than one communication step (of wall time) after it was due"}


@dataclass(frozen=True)
class Certificates:
    """The server's certificate (DER or PEM) and private key (PEM), and the folder of trusted client certificates."""

    certificate: Path
    private_key: Path
    trusted_clients: Path

    def problem(self) -> str | None:
        for what, path in (("certificate", self.certificate), ("private key", self.private_key)):
            if not path.is_file():
                return f"the server's {what} '{path}' is not a file"
        if not self.trusted_clients.is_dir():
            return f"the trusted client certificates '{self.trusted_clients}' is not a folder"
        return None


APPLICATION_URI = "urn:fishfmu:server"
"""The server's application URI: a server certificate names it (subjectAltName URI) for clients that check."""


class LineServer:
    """The co-simulation of a checked scenario behind an asyncua server (see the module docstring)."""

    def __init__(self, checked: CheckedScenario, endpoint: str = DEFAULT_ENDPOINT, allow_remote: bool = False,
                 realtime: float | None = None, user: str | None = None,
                 certificates: Certificates | None = None) -> None:
        problem = endpoint_problem(endpoint, allow_remote)
        if problem:
            raise InputError(problem, where="--endpoint")
        if certificates is not None and certificates.problem():
            raise InputError(certificates.problem(), where="--certificate")
        self.certificates = certificates
        self.user, self._password = user, None
        if user is not None:
            self._password = os.environ.get(PASSWORD_ENV)
            if not self._password:
                raise InputError(f"--user {user} needs the password in the environment variable {PASSWORD_ENV}",
                                 where="--user")
        if realtime is not None and not (0.0 < realtime <= 1000.0):
            raise InputError(f"{realtime} is not a real-time factor in (0, 1000]", where="--realtime")
        self.checked, self.endpoint, self.realtime = checked, endpoint, realtime
        self.scenario = checked.scenario
        self.fish = scenario_fish(self.scenario)
        self.names = signal_names(checked.wiring)
        self.external = list(checked.wiring.external)
        self.written: list[dict[str, Any]] = []
        """Every change clients made to an external input, with the simulated time from which it was used."""
        self.pacing = Pacing(realtime or 1.0, self.scenario.run.comm_step_s)
        self.state = "running"
        self.error: str | None = None
        self.stop_requested = asyncio.Event()
        self._stack = contextlib.ExitStack()
        self.cosim: CoSimulation | None = None
        self._nodes: dict[str, Any] = {}
        self._types: dict[str, Any] = {}
        self._last_written: dict[str, Any] = {}
        self._restarted = False
        self.behind: str | None = None

    # ---- the co-simulation ----------------------------------------------------------------------
    def start(self) -> None:
        """Build the co-simulation (its FMUs instantiated and initialised) before serving it."""
        self._start_cosim()

    def _start_cosim(self) -> None:
        self._stack.close()
        self._stack = contextlib.ExitStack()
        self.cosim = self._stack.enter_context(build(self.checked, self.fish))
        self.state, self.error = "running", None
        self._clear = ClearWatch(CLEAR_MARGIN_S)

    def close(self) -> None:
        self._stack.close()

    def _steps_left(self) -> int:
        dt = self.scenario.run.comm_step_s
        return max(0, int(round(self.scenario.run.duration_s / dt)) - self.cosim.steps)

    async def _take_writes(self) -> None:
        """Client writes to the external inputs, applied before the next step."""
        for key in self.external:
            value = await self._nodes[key].read_value()
            if value != self._last_written.get(key):
                self._last_written[key] = value
                self.cosim.set_external(key, value)
                self.written.append({"t_s": round(self.cosim.t_s, 9), "input": key, "value": value})

    def _step_once(self) -> None:
        try:
            self.cosim.step()
        except SimulationError as exc:
            self.state, self.error = f"failed: {exc}", str(exc)
            raise
        # the run ends where `fishfmu run` ends it: its duration, or (stop_when_clear) once every fish has left
        if self._steps_left() == 0 or (self.scenario.run.stop_when_clear and
                                       self._clear.done(self.cosim.t_s, self.cosim.plant.status)):
            self.state = "finished"

    async def _advance(self) -> bool:
        """One communication step with what clients wrote since the last; False when the run failed in it."""
        await self._take_writes()
        try:
            self._step_once()
        except SimulationError:
            return False
        return True

    async def step(self, n: int) -> float:
        """Lockstep: ``n`` communication steps (fewer at the end of the run); the new time."""
        for _ in range(max(0, int(n))):
            if self.state != "running" or not await self._advance():
                break
        await self._publish()
        return self.cosim.t_s

    # ---- the address space ----------------------------------------------------------------------
    async def _address_space(self, server: Any) -> None:
        from asyncua import ua
        idx = await server.register_namespace(NAMESPACE)
        folder = await server.nodes.objects.add_folder(ua.NodeId(FOLDER, idx), ua.QualifiedName(FOLDER, idx))
        types = _signal_info(self.checked)
        for name in ["fishfmu.time_s", "fishfmu.run_state", *self.names]:
            if name == "fishfmu.time_s":
                kind, unit, rng = "Real", "s", None
            elif name == "fishfmu.run_state":
                kind, unit, rng = "String", None, None
            else:
                kind, unit, rng = types[name]
            vtype, initial = {"Real": (ua.VariantType.Double, 0.0), "Integer": (ua.VariantType.Int32, 0),
                              "Enumeration": (ua.VariantType.Int32, 0), "Boolean": (ua.VariantType.Boolean, False),
                              "String": (ua.VariantType.String, "")}[kind]
            node = await folder.add_variable(ua.NodeId(name, idx), ua.QualifiedName(name, idx),
                                             ua.Variant(initial, vtype))
            if unit:
                code = _UNECE.get(unit)
                eu = ua.EUInformation(NamespaceUri="http://www.opcfoundation.org/UA/units/un/cefact",
                                      UnitId=_unit_id(code) if code else -1, DisplayName=ua.LocalizedText(unit),
                                      Description=ua.LocalizedText(unit))
                await node.add_property(idx, "EngineeringUnits", eu)
            if rng is not None:
                await node.add_property(idx, "EURange", ua.Range(Low=float(rng[0]), High=float(rng[1])))
            if name in self.external:
                await node.set_writable()
                await node.write_value(_variant(self.cosim.constants[name], vtype))
                self._last_written[name] = self.cosim.constants[name]
            self._nodes[name], self._types[name] = node, vtype

        async def _step(parent, n):  # noqa: ANN001 - asyncua's method signature
            if self.realtime is not None:  # the wall clock steps the line; a client's step would race it
                raise ua.UaStatusCodeError(ua.StatusCodes.BadInvalidState)
            return [ua.Variant(await self.step(n.Value), ua.VariantType.Double)]

        async def _stop(parent):  # noqa: ANN001
            if self.state == "running":
                self.state = "stopped"
            self.stop_requested.set()
            return []

        async def _reset(parent):  # noqa: ANN001
            self._start_cosim()
            self._restarted = True  # real time: pacing starts over from now
            for key in self.external:
                await self._nodes[key].write_value(_variant(self.cosim.constants[key], self._types[key]))
                self._last_written[key] = self.cosim.constants[key]
            await self._publish()
            return [ua.Variant(self.cosim.t_s, ua.VariantType.Double)]

        n_arg = ua.Argument(Name="n", DataType=ua.NodeId(ua.ObjectIds.Int32), ValueRank=-1,
                            Description=ua.LocalizedText("communication steps to advance"))
        t_out = ua.Argument(Name="time_s", DataType=ua.NodeId(ua.ObjectIds.Double), ValueRank=-1,
                            Description=ua.LocalizedText("simulated time after the steps, s"))
        await folder.add_method(ua.NodeId("fishfmu.step", idx), ua.QualifiedName("step", idx), _step, [n_arg],
                                [t_out])
        await folder.add_method(ua.NodeId("fishfmu.stop", idx), ua.QualifiedName("stop", idx), _stop, [], [])
        await folder.add_method(ua.NodeId("fishfmu.reset", idx), ua.QualifiedName("reset", idx), _reset, [],
                                [t_out])

    async def _publish(self) -> None:
        c = self.cosim
        values = {"fishfmu.time_s": c.t_s, "fishfmu.run_state": self.state}
        # the last recorded row (inputs as sent, outputs as they are); before the first step the start values
        row = c.signals[-1][1:] if c.signals else [c.values.get(k, c.constants.get(k)) for k in self.names]
        values.update(zip(self.names, row))
        for name, value in values.items():
            if name in self.external or value is None:
                continue
            await self._nodes[name].write_value(_variant(value, self._types[name]))

    # ---- serving --------------------------------------------------------------------------------
    async def serve(self, on_ready: Any = None, stop: Any = None) -> None:
        """Serve until the run ends (real time), a client calls stop(), or ``stop.requested`` (a signal)."""
        import logging

        from asyncua import Server, ua
        # asyncua warns on every start that a NoSecurity endpoint has no signing policy: what --allow-remote says
        logging.getLogger("asyncua").setLevel(logging.ERROR)
        server = Server(user_manager=_OneUser(self.user, self._password) if self.user else None)
        await server.init()
        if self.user:  # no anonymous sessions: only the named user
            server.set_identity_tokens([ua.UserNameIdentityToken])
        server.set_endpoint(self.endpoint)
        server.set_server_name("fishfmu line")
        await server.set_application_uri(APPLICATION_URI)
        if self.certificates is None:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        else:
            from asyncua.crypto.truststore import TrustStore
            from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
            c = self.certificates
            await server.load_certificate(str(c.certificate))
            await server.load_private_key(str(c.private_key))
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
            store = TrustStore([c.trusted_clients], [])
            await store.load()
            validator = CertificateValidator(CertificateValidatorOptions.TRUSTED_VALIDATION
                                             | CertificateValidatorOptions.PEER_CLIENT, store)
            server.set_certificate_validator(validator.validate)
        if self.cosim is None:
            self._start_cosim()
        await self._address_space(server)
        await self._publish()
        if stop is not None and stop.requested:  # a signal while starting: nothing to serve
            return
        async with server:
            if on_ready is not None:
                on_ready(self)
            if self.realtime is None:
                while not self.stop_requested.is_set() and not (stop is not None and stop.requested):
                    with contextlib.suppress(asyncio.TimeoutError):
                        await asyncio.wait_for(self.stop_requested.wait(), 0.05)
            else:
                await self._run_realtime(stop)

    async def _run_realtime(self, stop: Any) -> None:
        dt_wall = self.scenario.run.comm_step_s / self.realtime
        start = time.monotonic()
        warned = False
        k = 0
        while self.state == "running" and not self.stop_requested.is_set() and not (stop and stop.requested):
            if self._restarted:
                start, k, self._restarted = time.monotonic(), 0, False
            due = start + k * dt_wall
            now = time.monotonic()
            if now < due:
                await asyncio.sleep(due - now)
                now = time.monotonic()
            else:
                await asyncio.sleep(0)  # let clients in even when late
            self.pacing.lateness_s.append(now - due)
            if not await self._advance():
                break
            await self._publish()
            k += 1
            if not warned and k >= 100 and np.median(self.pacing.lateness_s[-100:]) > dt_wall:
                warned = True
                n_fish = int(np.sum(self.cosim.plant.fish_state().status == ON_LINE))
                self.behind = (f"cannot keep up with real time x{self.realtime:g}: at t = {self.cosim.t_s:.2f} s the "
                               f"median lateness of the last 100 steps is "
                               f"{1e3 * float(np.median(self.pacing.lateness_s[-100:])):.1f} ms "
                               f"({n_fish} fish in play)")
                print(self.behind, flush=True)

    def result(self, status: str, wall_s: float) -> RunResult:
        c = self.cosim
        error = self.error if self.error else (None if status == "ok" else
                                               f"stopped by a signal at t = {c.t_s:.3f} s")
        res = collect(self.scenario, self.fish, c.plant, c.recorder, c, status, error, {}, wall_s)
        res.wiring = self.checked.wiring.describe()
        res.served = {"endpoint": self.endpoint, "mode": "lockstep" if self.realtime is None else "realtime",
                      "namespace": NAMESPACE, "external_inputs": self.external, "writes": self.written,
                      "ended": ("the scenario's end" if self.state == "finished" else
                                "stop() called by a client" if self.stop_requested.is_set() else
                                self.error or "a signal"),
                      **({"pacing": self.pacing.summary()} if self.realtime is not None else {}),
                      **({"behind": self.behind} if self.behind else {})}
        return res


class _OneUser:
    """asyncua's user manager for one named user with a password (compared in constant time)."""

    def __init__(self, name: str, password: str) -> None:
        self.name, self.password = name, password

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> Any:
        from asyncua.crypto.permission_rules import User, UserRole
        if username == self.name and password is not None and hmac.compare_digest(password.encode(),
                                                                                   self.password.encode()):
            return User(role=UserRole.User, name=username)
        return None


def _variant(value: Any, vtype: Any) -> Any:
    """``value`` as an OPC UA Variant of its node's type (a Real signal holding an int is still a Double)."""
    from asyncua import ua
    cast = {ua.VariantType.Double: float, ua.VariantType.Int32: int, ua.VariantType.Boolean: bool,
            ua.VariantType.String: str}[vtype]
    return ua.Variant(cast(value), vtype)


def _signal_info(checked: CheckedScenario) -> dict[str, tuple[str, str | None, tuple[float, float] | None]]:
    """Per signal: its type, unit and declared (min, max) where both are given."""
    out = {}
    for key in signal_names(checked.wiring):
        comp, _, var = key.partition(".")
        if comp == PLANT:
            signal = var.rpartition(".")[2]
            out[key] = ("Boolean" if signal == "blocked" else "Real", PLANT_UNITS.get(signal), None)
            continue
        v = checked.opened[comp].variables[var]
        md_var = next((m for m in checked.opened[comp].model_description.modelVariables if m.name == var), None)
        lo, hi = getattr(md_var, "min", None), getattr(md_var, "max", None)
        rng = (float(lo), float(hi)) if lo is not None and hi is not None else None
        out[key] = (v.type, v.unit, rng)
    return out


def serve_scenario(scenario_file: str | Path, out: Path, overrides: dict[str, Any] | None = None, *,
                   endpoint: str = DEFAULT_ENDPOINT, realtime: float | None = None, allow_remote: bool = False,
                   user: str | None = None, certificates: Certificates | None = None,
                   overwrite: bool = False, report: bool = True, on_ready: Any = None) -> ServeOutcome:
    """Check the scenario, serve it until it ends or is stopped, write the run into ``out``."""
    from fishfmu.commands import run_inputs
    from fishfmu.cosim.build import checked
    from fishfmu.cosim.stop import stop_on_signals
    from fishfmu.output.run_folder import mark_running, prepare_out_dir, write_outputs
    from fishfmu.scenario.schema import load_scenario
    from fishfmu.session import register_output
    scenario_file = Path(scenario_file)
    sc = load_scenario(scenario_file, overrides or {})
    problem = endpoint_problem(endpoint, allow_remote)
    if problem:
        raise InputError(problem, where="--endpoint")
    with checked(sc, scenario_file) as c:
        line = LineServer(c, endpoint, allow_remote, realtime, user, certificates)
        out_dir = prepare_out_dir(out, overwrite, run_inputs(scenario_file, sc, None), "serve")
        t0 = time.perf_counter()
        # a signal from here on only sets a flag: the server ends at its next look and the run is written
        with stop_on_signals() as stop:
            mark_running(out_dir, scenario_file)
            register_output(out_dir)
            try:
                line.start()
                asyncio.run(line.serve(on_ready, stop))
                # ended by the scenario's end or by a client's stop(): a complete run; by a signal: partial
                ended = line.state == "finished" or line.stop_requested.is_set()
                status = "failed" if line.error else "ok" if ended else "partial"
                result = line.result(status, time.perf_counter() - t0)
                write_outputs(result, out_dir, report=report)
            finally:
                line.close()
    return ServeOutcome(result, out_dir, stop.exit_code if status == "partial" else None)


@dataclass(frozen=True)
class ServeOutcome:
    result: RunResult
    out_dir: Path
    stop_exit_code: int | None
