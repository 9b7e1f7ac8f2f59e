"""``fishfmu serve``: the line as an OPC UA server, for a PLC to commission against (asyncua).

Address space: a folder ``fishfmu`` under Objects, in the namespace ``urn:fishfmu``, with one variable per
signal of the run (every connected variable, constant input, external input and ``[record]``ed variable,
named as the scenario names it: ``plant.pe_c4.blocked``, ``drive_c1.belt_speed``, node id ``s=<that name>``)
and every output of the plant (each belt's ``speed``, ``load_force`` and ``load_mass``, each photo-eye's
``blocked``), recorded or not: a PLC always needs its sensors.  Each has its OPC UA data type (Double,
Int32/Int64, Boolean, String) and, where the FMU or plant port gives a unit, an ``EngineeringUnits`` property
(and ``EURange`` from a declared min/max).  Besides: ``fishfmu.time_s``, ``fishfmu.run_state`` (``running``,
``finished``, ``stopped``, ``failed: ...``), the fish counts ``fishfmu.fish_waiting``, ``fishfmu.fish_on_line``
and ``fishfmu.fish_left``, and the methods ``step(n)``, ``stop()`` and ``reset()``.

Only the inputs of ``[opcua] inputs`` are writable: a value written by a client is used from the next
communication step on, as a PLC's outputs are on its next scan.  A write the input cannot take is refused with
its status and changes nothing: an array or a value of another type (BadTypeMismatch), a value outside the
variable's declared range or not finite (BadOutOfRange), a bad status or an index range (BadWriteNotSupported).
A method called with the wrong arguments answers BadArgumentsMissing, BadTooManyArguments or BadInvalidArgument
(``step(n)`` takes one integer n >= 0).

The line is stepped in one worker thread, never in the server's event loop: while it steps, the server answers
reads, writes, other clients and ``stop()``; a ``step(n)`` publishes its progress every 0.1 s of wall time and
ends early, between two communication steps, on ``stop()``, ``reset()`` or a signal.  ``reset()`` starts the run
over (and forgets what clients wrote in the run it discards).

Two ways to advance:

* **lockstep**: the line moves only when a client calls ``step(n)`` (n communication steps; returns the new
  time): deterministic tests of PLC logic, the same results as a run of the same scenario and seed when the
  client writes what the controller FMU would have;
* **real time** (``--realtime FACTOR``, 0.001 to 1000): step k is due at ``start + k dt / FACTOR`` on the
  monotonic clock (the wait for it ends at once on ``stop()``, ``reset()`` or a signal);
  the lateness of each step's start against its due time is measured, and a step starting more than one
  communication step late counts as an overrun.  p50/p99/max lateness and the overrun count go to
  ``run_info.json`` (``served``) and the console; when the line cannot keep up (the median lateness grows
  beyond a step) the console says so, with the time and the number of fish on the line.

The run ends at ``run.duration_s`` (real time), or when a client calls ``stop()``, or on Ctrl-C/SIGTERM (within a
communication step and 0.05 s); it is then written like any run (KPIs, signals with every value clients wrote, the
run in the measured-data format).  Bad options (an endpoint without a port of 1-65535, a port in use, a real-time
factor out of bounds, certificate or key files the server cannot use, --user without a password) are refused before
the output folder is made; whatever fails after leaves ``run_info.json`` at ``failed``, never at ``running``.

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
import errno
import hmac
import ipaddress
import logging
import math
import os
import re
import socket
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import numpy as np

from plant.errors import InputError, SimulationError, one_line
from plant.sim.plant import LEFT, ON_LINE, WAITING
from plant.sim.simulate import ClearWatch

from fishfmu.cosim.build import BuildFailed, CheckedScenario, build, scenario_fish
from fishfmu.cosim.master import CoSimulation
from fishfmu.cosim.results import RunResult
from fishfmu.cosim.runner import CLEAR_MARGIN_S, collect
from fishfmu.scenario.wiring import PLANT, PLANT_UNITS, signal_names

NAMESPACE = "urn:fishfmu"
FOLDER = "fishfmu"
DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840"
PASSWORD_ENV = "FISHFMU_OPCUA_PASSWORD"
REALTIME_RANGE = (1e-3, 1e3)
"""Real-time factors served: x0.001 is one 10 ms step per 10 s of wall time, x1000 more than any line keeps up with."""
POLL_S = 0.05
"""How often the event loop looks for a signal (a Python signal handler cannot wake it) and a due step."""
PUBLISH_EVERY_S = 0.1
"""Wall time between two publications of a long step(n)'s progress."""
MAX_CERTIFICATE_BYTES = 1 << 20
"""A certificate or key file larger than this is not one (refused before it is read)."""

# UNECE Recommendation 20 codes for the units the line uses (OPC UA Part 8, EUInformation.UnitId)
_UNECE = {"m": "MTR", "m/s": "MTS", "s": "SEC", "N": "NEW", "kg": "KGM", "rpm": "RPM", "1/min": "RPM",
          "rad/s": "2A", "A": "AMP", "V": "VLT", "W": "WTT", "Hz": "HTZ", "K": "KEL", "degC": "CEL"}
_FISH_COUNTS = {"fishfmu.fish_waiting": WAITING, "fishfmu.fish_on_line": ON_LINE, "fishfmu.fish_left": LEFT}


def _unit_id(code: str) -> int:
    """The UnitId of a UNECE code as OPC UA Part 8 defines it (each character's code, big-endian)."""
    out = 0
    for ch in code.rjust(3, "\0")[-3:]:
        out = (out << 8) | ord(ch)
    return out


def _host_port(endpoint: str) -> tuple[str, int] | None:
    """The host and port of an ``opc.tcp://HOST:PORT`` endpoint, or None when it is not one (a port must be
    1-65535: 0 would listen on a port nobody is told)."""
    url = urlparse(endpoint)
    try:
        port = url.port
    except ValueError:  # not a number, or out of 0-65535
        return None
    if url.scheme != "opc.tcp" or not url.hostname or port is None or not 1 <= port <= 65535:
        return None
    return url.hostname, port


def endpoint_problem(endpoint: str, allow_remote: bool) -> str | None:
    """Why the server must not listen at ``endpoint``, or None."""
    where = _host_port(endpoint)
    if where is None:
        return f"'{endpoint}' is not an endpoint of the form opc.tcp://HOST:PORT with a port of 1 to 65535"
    if allow_remote:
        return None
    host = where[0]
    try:
        local = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        local = False
    if not local:
        return (f"'{host}' is not the loopback interface: other hosts could write the line's inputs without a user "
                "check; give --allow-remote to open it on purpose")
    return None


def listen_problem(endpoint: str) -> str | None:
    """Why nothing can listen at ``endpoint`` now (the port taken, the address not this machine's), or None.
    Binds each address as asyncio's server will (SO_REUSEADDR) and lets it go again."""
    host, port = _host_port(endpoint)
    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        return f"'{host}' cannot be resolved to an address of this machine ({exc.strerror})"
    bound, unavailable = 0, None
    for family, kind, proto, _, address in addresses:
        with socket.socket(family, kind, proto) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                s.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            try:
                s.bind(address)
            except OSError as exc:
                if exc.errno != errno.EADDRNOTAVAIL:
                    return _listen_error(host, port, exc)
                unavailable = exc  # asyncio skips an address family the machine has not enabled, so do we
                continue
            bound += 1
    return _listen_error(host, port, unavailable) if not bound and unavailable is not None else None


def _listen_error(host: str, port: int, exc: OSError) -> str:
    if exc.errno == errno.EADDRINUSE:
        return f"port {port} on {host} is in use (another server listens there): choose another port"
    if exc.errno == errno.EADDRNOTAVAIL:
        return f"'{host}' is not an address of this machine"
    if exc.errno == errno.EACCES:
        return f"port {port} on {host} may not be opened by this user (ports below 1024 need privileges)"
    return f"cannot listen at {host}:{port}: {exc.strerror or exc}"


def realtime_problem(factor: float | None) -> str | None:
    """Why ``factor`` is not a real-time factor the server paces to, or None."""
    lo, hi = REALTIME_RANGE
    if factor is None or (math.isfinite(factor) and lo <= factor <= hi):
        return None
    return (f"{factor:g} is not a real-time factor in [{lo:g}, {hi:g}] (x{lo:g}: one 10 ms step every 10 s of "
            "wall time)")


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
    """The server's certificate (DER or PEM) and private key (PEM), and the folder of trusted client certificates.

    Read as asyncua reads them: a file whose name ends in ``.pem`` as PEM, any other as DER; in the folder, every
    file whose name has a dot and contains ``der`` or ``pem``."""

    certificate: Path
    private_key: Path
    trusted_clients: Path

    def problem(self) -> tuple[str, str] | None:
        """(the option, what is wrong with its file) for the first file the server could not use, or None."""
        from cryptography.hazmat.primitives.asymmetric import rsa
        cert = _read_crypto(self.certificate, "certificate")
        if isinstance(cert, str):
            return "--certificate", cert
        key = _read_crypto(self.private_key, "private key")
        if isinstance(key, str):
            return "--private-key", key
        if not isinstance(key, rsa.RSAPrivateKey) or not 2048 <= key.key_size <= 4096:
            return "--private-key", (f"'{self.private_key}' is not an RSA key of 2048 to 4096 bits, which the "
                                     "Basic256Sha256 policy needs")
        if cert.public_key().public_numbers() != key.public_key().public_numbers():
            return "--private-key", f"'{self.private_key}' is not the key of the certificate '{self.certificate}'"
        folder = self.trusted_clients
        if not folder.is_dir():
            return "--trusted-clients", f"'{folder}' is not a folder"
        try:
            files = sorted(f for f in folder.glob("*.*") if re.match(".*(der|pem)", f.name.lower()))
        except OSError as exc:
            return "--trusted-clients", f"'{folder}' cannot be read ({exc.strerror or exc})"
        for f in files:
            loaded = _read_crypto(f, "certificate")
            if isinstance(loaded, str):
                return "--trusted-clients", f"{loaded}; the folder holds only client certificates"
        if not files:
            return "--trusted-clients", (f"'{folder}' holds no certificate (a file named *.der or *.pem): no client "
                                         "could connect")
        return None


def _read_crypto(path: Path, what: str) -> Any:
    """The certificate or private key in ``path``, or what is wrong with the file (a str)."""
    from cryptography import x509
    from cryptography.exceptions import UnsupportedAlgorithm
    from cryptography.hazmat.primitives import serialization
    pem = path.suffix.lower() == ".pem"  # asyncua's rule (uacrypto.load_certificate / load_private_key)
    form = "PEM" if pem else "DER (a name not ending in .pem is read as DER)"
    try:
        if not path.is_file():
            return f"'{path}' is not a file"
        if path.stat().st_size > MAX_CERTIFICATE_BYTES:
            return f"'{path}' is larger than 1 MiB: not a {what}"
        data = path.read_bytes()
    except OSError as exc:
        return f"'{path}' cannot be read ({exc.strerror or exc})"
    try:
        if what == "certificate":
            return x509.load_pem_x509_certificate(data) if pem else x509.load_der_x509_certificate(data)
        return (serialization.load_pem_private_key(data, password=None) if pem else
                serialization.load_der_private_key(data, password=None))
    except TypeError:  # a key with a password: the server has none to give
        return f"'{path}' is an encrypted private key: give it without a password"
    except (ValueError, UnsupportedAlgorithm):
        return f"'{path}' is not a {what} in {form}"


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
        problem = certificates.problem() if certificates is not None else None
        if problem:
            raise InputError(problem[1], where=problem[0])
        self.certificates = certificates
        self.user, self._password = user, None
        if user is not None:
            self._password = os.environ.get(PASSWORD_ENV)
            if not self._password:
                raise InputError(f"--user {user} needs the password in the environment variable {PASSWORD_ENV}",
                                 where="--user")
        problem = realtime_problem(realtime)
        if problem:
            raise InputError(problem, where="--realtime")
        self.checked, self.endpoint, self.realtime = checked, endpoint, realtime
        self.scenario = checked.scenario
        self.fish = scenario_fish(self.scenario)
        self.names = signal_names(checked.wiring)
        sc = self.scenario
        plant_outputs = [*(f"{PLANT}.{c.id}.{s}" for c in sc.line.conveyors for s in ("speed", "load_force",
                                                                                          "load_mass")),
                         *(f"{PLANT}.{p.id}.blocked" for p in sc.line.photoeyes)]
        self.served = [*self.names, *(k for k in plant_outputs if k not in self.names)]
        """Every signal in the address space: the run's signals, then the plant's outputs it does not record."""
        self.external = list(checked.wiring.external)
        self.written: list[dict[str, Any]] = []
        """Every change clients made to an external input in this run (since the last reset), with the simulated
        time from which it was used."""
        self.pacing = Pacing(realtime or 1.0, self.scenario.run.comm_step_s)
        self.state = "running"
        self.error: str | None = None
        self.resets = 0
        self.stop_requested = threading.Event()
        """A client called stop()."""
        self._interrupt = threading.Event()
        """stop(), reset() or the end of serving: a step(n) under way ends after its current step."""
        self._signal: Any = None
        self._crash: BaseException | None = None
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fishfmu-line")
        """The one thread that builds, steps and closes the line: never two steps at once, never in the event loop."""
        self._lock: asyncio.Lock | None = None
        self._stack = contextlib.ExitStack()
        self.cosim: CoSimulation | None = None
        self._build_failed: BuildFailed | None = None
        self._aspace: Any = None
        self._nodes: dict[str, Any] = {}
        self._types: dict[str, Any] = {}
        self._ranges: dict[str, tuple[float, float] | None] = {}
        self._last_written: dict[str, Any] = {}
        self._restarted = False
        self.behind: str | None = None

    # ---- the co-simulation (in the worker thread) --------------------------------------------------
    def start(self) -> None:
        """Build the co-simulation (its FMUs instantiated and initialised) before serving it; an FMU failing in
        that leaves ``cosim`` None and the state failed."""
        self._worker.submit(self._start_cosim).result()

    def _start_cosim(self) -> None:
        self._stack.close()
        self._stack = contextlib.ExitStack()
        self.cosim, self._build_failed = None, None
        try:
            self.cosim = self._stack.enter_context(build(self.checked, self.fish))
        except BuildFailed as exc:
            self._build_failed = exc
            self.state, self.error = f"failed: {exc}", str(exc)
            return
        self.state, self.error = "running", None
        self._clear = ClearWatch(CLEAR_MARGIN_S)

    def close(self) -> None:
        """Terminate the FMUs and free the plant (in the worker thread, after whatever it still does)."""
        with contextlib.suppress(RuntimeError):  # already shut down
            self._worker.submit(self._stack.close).result()
        self._worker.shutdown(wait=True)

    def _steps_left(self) -> int:
        dt = self.scenario.run.comm_step_s
        return max(0, int(round(self.scenario.run.duration_s / dt)) - self.cosim.steps)

    def _take_writes(self) -> None:
        """Client writes to the external inputs, applied before the next step (read from the address space
        directly: a plain read, safe from this thread)."""
        from asyncua import ua
        for key in self.external:
            value = self._aspace.read_attribute_value(self._nodes[key].nodeid, ua.AttributeIds.Value).Value.Value
            if value != self._last_written.get(key):
                self._last_written[key] = value
                self.cosim.set_external(key, value)
                self.written.append({"t_s": round(self.cosim.t_s, 9), "input": key, "value": value})

    def _step_once(self) -> bool:
        """One communication step; False when the run failed in it."""
        try:
            self.cosim.step()
        except SimulationError as exc:
            self.state, self.error = f"failed: {exc}", str(exc)
            return False
        # the run ends where `fishfmu run` ends it: its duration, or (stop_when_clear) once every fish has left
        if self._steps_left() == 0 or (self.scenario.run.stop_when_clear and
                                       self._clear.done(self.cosim.t_s, self.cosim.plant.status)):
            self.state = "finished"
        return True

    def _interrupted(self) -> bool:
        return self._interrupt.is_set() or (self._signal is not None and self._signal.requested)

    def _run_steps(self, n: int, budget_s: float) -> int:
        """Up to ``n`` steps with what clients wrote before each; fewer at the run's end or failure, on an
        interrupt (stop(), reset(), a signal) and after ``budget_s`` of wall time.  The steps made."""
        done, until = 0, time.monotonic() + budget_s
        try:
            while done < n and self.cosim is not None and self.state == "running" and not self._interrupted():
                self._take_writes()
                if not self._step_once():
                    break
                done += 1
                if time.monotonic() >= until:
                    break
        except Exception as exc:  # a bug: end serving and report it (exit 4), never step on after it
            self._crash = exc
            self.state, self.error = "failed: internal error", f"{type(exc).__name__}: {exc}"
        return done

    async def _in_worker(self, fn: Any, *args: Any) -> Any:
        return await asyncio.get_running_loop().run_in_executor(self._worker, fn, *args)

    async def step(self, n: int) -> float:
        """Lockstep: ``n`` communication steps (fewer at the end of the run, or when stop(), reset() or a signal
        comes first); the new time.  Progress is published every PUBLISH_EVERY_S while it steps."""
        async with self._lock:
            left = n
            while left > 0 and self.state == "running" and not self._interrupted():
                done = await self._in_worker(self._run_steps, left, PUBLISH_EVERY_S)
                left -= done
                if done == 0 or left == 0:
                    break
                await self._publish()  # the progress of a long step, for readers
            await self._publish()
            return self.cosim.t_s if self.cosim is not None else 0.0

    # ---- the address space ----------------------------------------------------------------------
    async def _address_space(self, server: Any) -> None:
        from asyncua import ua
        self._aspace = server.iserver.aspace
        idx = await server.register_namespace(NAMESPACE)
        folder = await server.nodes.objects.add_folder(ua.NodeId(FOLDER, idx), ua.QualifiedName(FOLDER, idx))
        types = _signal_info(self.checked, self.served)
        extra = {"fishfmu.time_s": ("Real", "s", None), "fishfmu.run_state": ("String", None, None),
                 **{k: ("Integer", None, None) for k in _FISH_COUNTS}}
        for name in [*extra, *self.served]:
            kind, unit, rng = extra[name] if name in extra else types[name]
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
            self._nodes[name], self._types[name], self._ranges[name] = node, vtype, rng
            if name in self.external:
                await node.set_writable()
                start = self.checked.wiring.constants[name]
                await node.write_value(_variant(start, vtype))
                self._last_written[name] = start
        self._guard_writes(server)

        def refused(code: Any, per_argument: list[Any] | None = None) -> Any:
            return ua.CallMethodResult(StatusCode=ua.StatusCode(code),
                                       InputArgumentResults=[ua.StatusCode(c) for c in per_argument or []])

        integer_types = {ua.VariantType.SByte, ua.VariantType.Byte, ua.VariantType.Int16, ua.VariantType.UInt16,
                         ua.VariantType.Int32, ua.VariantType.UInt32, ua.VariantType.Int64, ua.VariantType.UInt64}

        async def _step(parent, *args):  # noqa: ANN001, ANN002 - asyncua's method signature
            if self.realtime is not None:  # the wall clock steps the line; a client's step would race it
                return refused(ua.StatusCodes.BadInvalidState)
            if not args:
                return refused(ua.StatusCodes.BadArgumentsMissing)
            if len(args) > 1:
                return refused(ua.StatusCodes.BadTooManyArguments)
            n = args[0]
            if (not isinstance(n, ua.Variant) or n.VariantType not in integer_types or n.is_array
                    or not isinstance(n.Value, int) or isinstance(n.Value, bool)):
                return refused(ua.StatusCodes.BadInvalidArgument, [ua.StatusCodes.BadTypeMismatch])
            if n.Value < 0:
                return refused(ua.StatusCodes.BadInvalidArgument, [ua.StatusCodes.BadOutOfRange])
            return [ua.Variant(await self.step(n.Value), ua.VariantType.Double)]

        async def _stop(parent, *args):  # noqa: ANN001, ANN002
            if args:
                return refused(ua.StatusCodes.BadTooManyArguments)
            self.stop_requested.set()
            self._interrupt.set()  # a step(n) under way ends after its current step
            async with self._lock:
                if self.state == "running":
                    self.state = "stopped"
                await self._publish()
            return []

        async def _reset(parent, *args):  # noqa: ANN001, ANN002
            if args:
                return refused(ua.StatusCodes.BadTooManyArguments)
            self._interrupt.set()
            async with self._lock:
                await self._in_worker(self._start_cosim)
                self._interrupt.clear()
                # the run written is the one after the reset: what clients wrote before it is gone with it
                self.written.clear()
                self.pacing.lateness_s.clear()
                self.behind = None
                self.resets += 1
                self._restarted = True  # real time: pacing starts over from now
                for key in self.external:
                    start = self.checked.wiring.constants[key]
                    await self._nodes[key].write_value(_variant(start, self._types[key]))
                    self._last_written[key] = start
                await self._publish()
                return [ua.Variant(self.cosim.t_s if self.cosim is not None else 0.0, ua.VariantType.Double)]

        n_arg = ua.Argument(Name="n", DataType=ua.NodeId(ua.ObjectIds.Int32), ValueRank=-1,
                            Description=ua.LocalizedText("communication steps to advance (0 or more)"))
        t_out = ua.Argument(Name="time_s", DataType=ua.NodeId(ua.ObjectIds.Double), ValueRank=-1,
                            Description=ua.LocalizedText("simulated time after the steps, s"))
        await folder.add_method(ua.NodeId("fishfmu.step", idx), ua.QualifiedName("step", idx), _step, [n_arg],
                                [t_out])
        await folder.add_method(ua.NodeId("fishfmu.stop", idx), ua.QualifiedName("stop", idx), _stop, [], [])
        await folder.add_method(ua.NodeId("fishfmu.reset", idx), ua.QualifiedName("reset", idx), _reset, [],
                                [t_out])

    def _write_refusal(self, key: str, value: Any) -> Any:
        """The status a write of the DataValue ``value`` to the external input ``key`` is refused with, or None.
        asyncua checks a written Variant's type, not its shape nor its value."""
        from asyncua import ua
        if value.StatusCode is not None and not value.StatusCode.is_good():
            return ua.StatusCodes.BadWriteNotSupported  # asyncua would store a null the line cannot use
        v = value.Value
        if v is None or v.VariantType != self._types[key] or v.is_array or v.Dimensions:
            return ua.StatusCodes.BadTypeMismatch
        x = v.Value
        if isinstance(x, float) and not math.isfinite(x):
            return ua.StatusCodes.BadOutOfRange
        rng = self._ranges[key]
        if rng is not None and isinstance(x, (int, float)) and not rng[0] <= x <= rng[1]:
            return ua.StatusCodes.BadOutOfRange
        return None

    def _guard_writes(self, server: Any) -> None:
        """Refuse, item by item, the writes an external input cannot take (see :meth:`_write_refusal`), before
        asyncua's attribute service stores them."""
        from asyncua import ua
        service = server.iserver.attribute_service
        write = service.write
        inputs = {self._nodes[k].nodeid: k for k in self.external}

        async def guarded(params: Any, *args: Any, **kwargs: Any) -> list[Any]:
            refusals: dict[int, Any] = {}
            for i, item in enumerate(params.NodesToWrite):
                key = inputs.get(item.NodeId)
                if key is None:
                    continue
                if item.AttributeId == ua.AttributeIds.Value and item.IndexRange:
                    refusals[i] = ua.StatusCodes.BadWriteNotSupported
                elif item.AttributeId == ua.AttributeIds.Value:
                    code = self._write_refusal(key, item.Value)
                    if code is not None:
                        refusals[i] = code
            if not refusals:
                return await write(params, *args, **kwargs)
            rest = [item for i, item in enumerate(params.NodesToWrite) if i not in refusals]
            done = iter(await write(ua.WriteParameters(NodesToWrite=rest), *args, **kwargs) if rest else [])
            return [ua.StatusCode(refusals[i]) if i in refusals else next(done)
                    for i in range(len(params.NodesToWrite))]

        service.write = guarded

    async def _publish(self) -> None:
        c = self.cosim
        values: dict[str, Any] = {"fishfmu.time_s": c.t_s if c is not None else 0.0, "fishfmu.run_state": self.state}
        if c is not None:
            # the last recorded row (inputs as sent, outputs as they are); before the first step the start values;
            # the plant's outputs not recorded as they are now
            row = c.signals[-1][1:] if c.signals else [c.values.get(k, c.constants.get(k)) for k in self.names]
            values.update(zip(self.names, row))
            values.update((k, c.values.get(k)) for k in self.served[len(self.names):])
            status = c.plant.status
            values.update((k, int(np.count_nonzero(status == s))) for k, s in _FISH_COUNTS.items())
        for name, value in values.items():
            if name in self.external or value is None:
                continue
            await self._nodes[name].write_value(_variant(value, self._types[name]))

    # ---- serving --------------------------------------------------------------------------------
    def _ending(self) -> bool:
        """Serving ends: a client's stop(), a signal, or a bug in a step."""
        return (self.stop_requested.is_set() or self._crash is not None
                or (self._signal is not None and self._signal.requested))

    async def serve(self, on_ready: Any = None, stop: Any = None) -> None:
        """Serve until the run ends (real time), a client calls stop(), or ``stop.requested`` (a signal).
        Raises InputError naming --endpoint when the server cannot listen there."""
        from asyncua import Server, ua
        _quiet_asyncua()
        self._signal, self._lock = stop, asyncio.Lock()
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
        if self.cosim is None and self._build_failed is None:
            await self._in_worker(self._start_cosim)
        if self.cosim is None:  # an FMU failed while the line was built: nothing to serve
            return
        await self._address_space(server)
        await self._publish()
        if stop is not None and stop.requested:  # a signal while starting: nothing to serve
            return
        logger = logging.getLogger("asyncua")
        level, logger.level = logger.level, logging.CRITICAL + 1  # its traceback of a failed start: ours says it
        try:
            await server.start()
        except OSError as exc:
            host, port = _host_port(self.endpoint)
            raise InputError(_listen_error(host, port, exc), where="--endpoint") from None
        finally:
            logger.setLevel(level)
        try:
            if on_ready is not None:
                on_ready(self)
            if self.realtime is None:
                while not self._ending():
                    await asyncio.sleep(POLL_S)
            else:
                await self._run_realtime()
            self._interrupt.set()
            async with self._lock:  # a step(n) under way ends after its current step
                if self.state == "running" and self.stop_requested.is_set():
                    self.state = "stopped"
        finally:
            await server.stop()
        if self._crash is not None:
            raise self._crash

    async def _sleep_until(self, due: float) -> bool:
        """Wait for the monotonic time ``due``, looking for the end of serving and a reset every POLL_S;
        False when one of them came first."""
        await asyncio.sleep(0)  # let clients in even when late
        while (now := time.monotonic()) < due:
            if self._ending() or self._restarted:
                return False
            await asyncio.sleep(min(due - now, POLL_S))
        return True

    async def _run_realtime(self) -> None:
        dt_wall = self.scenario.run.comm_step_s / self.realtime
        start, k, warned = time.monotonic(), 0, False
        while not self._ending():
            if self._restarted:
                start, k, warned, self._restarted = time.monotonic(), 0, False, False
            if self.state != "running":  # the run's end, or a failure
                break
            due = start + k * dt_wall
            if not await self._sleep_until(due):
                continue
            now = time.monotonic()
            async with self._lock:
                if self._restarted or self._ending() or self.state != "running":
                    continue
                self.pacing.lateness_s.append(now - due)
                await self._in_worker(self._run_steps, 1, math.inf)
                await self._publish()
            k += 1
            if not warned and k >= 100 and np.median(self.pacing.lateness_s[-100:]) > dt_wall:
                warned = True
                n_fish = int(np.sum(self.cosim.plant.status == ON_LINE))
                self.behind = (f"cannot keep up with real time x{self.realtime:g}: at t = {self.cosim.t_s:.2f} s the "
                               f"median lateness of the last 100 steps is "
                               f"{1e3 * float(np.median(self.pacing.lateness_s[-100:])):.1f} ms "
                               f"({n_fish} fish in play)")
                print(self.behind, flush=True)

    def result(self, status: str, wall_s: float) -> RunResult:
        """The served run as a RunResult (collected in the worker thread, after all its steps)."""
        return self._worker.submit(self._result, status, wall_s).result()

    def _result(self, status: str, wall_s: float) -> RunResult:
        c = self.cosim
        error = self.error if self.error else (None if status == "ok" else
                                               f"stopped by a signal at t = {c.t_s:.3f} s")
        if c is None:  # an FMU failed while the line was built
            failed = self._build_failed
            res = collect(self.scenario, self.fish, failed.plant, failed.recorder, None, status, error, {}, wall_s,
                          self.names)
        else:
            res = collect(self.scenario, self.fish, c.plant, c.recorder, c, status, error, {}, wall_s)
        res.wiring = self.checked.wiring.describe()
        res.served = {"endpoint": self.endpoint, "mode": "lockstep" if self.realtime is None else "realtime",
                      "namespace": NAMESPACE, "external_inputs": self.external, "writes": self.written,
                      "resets": self.resets,
                      "ended": ("the scenario's end" if self.state == "finished" else
                                "stop() called by a client" if self.stop_requested.is_set() else
                                self.error or "a signal"),
                      **({"pacing": self.pacing.summary()} if self.realtime is not None else {}),
                      **({"behind": self.behind} if self.behind else {})}
        return res


def _quiet_asyncua() -> None:
    """asyncua's errors as one line each on stderr, without tracebacks (a client's bad request is not fishfmu's
    bug); its warnings (a NoSecurity endpoint has no signing policy: what --allow-remote says) not at all."""
    logger = logging.getLogger("asyncua")
    logger.setLevel(logging.ERROR)
    if not any(isinstance(h.formatter, _OneLine) for h in logger.handlers):
        handler = logging.StreamHandler()
        handler.setFormatter(_OneLine())
        logger.addHandler(handler)
        logger.propagate = False


class _OneLine(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        exc = record.exc_info[1] if record.exc_info else None
        if exc is not None:
            text += f" ({type(exc).__name__}: {exc})"
        return one_line(f"opcua: {text}")


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


def _signal_info(checked: CheckedScenario, keys: list[str]
                 ) -> dict[str, tuple[str, str | None, tuple[float, float] | None]]:
    """Per signal: its type, unit and declared (min, max) where both are given."""
    out = {}
    for key in keys:
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


def options_problem(endpoint: str, allow_remote: bool, realtime: float | None,
                    certificates: Certificates | None) -> InputError | None:
    """What is wrong with the server's options (before the scenario is read), as the InputError to raise."""
    problem = endpoint_problem(endpoint, allow_remote)
    if problem:
        return InputError(problem, where="--endpoint")
    problem = realtime_problem(realtime)
    if problem:
        return InputError(problem, where="--realtime")
    found = certificates.problem() if certificates is not None else None
    return InputError(found[1], where=found[0]) if found else None


def serve_scenario(scenario_file: str | Path, out: Path, overrides: dict[str, Any] | None = None, *,
                   endpoint: str = DEFAULT_ENDPOINT, realtime: float | None = None, allow_remote: bool = False,
                   user: str | None = None, certificates: Certificates | None = None,
                   overwrite: bool = False, report: bool = True, on_ready: Any = None) -> ServeOutcome:
    """Check the options and the scenario, serve it until it ends or is stopped, write the run into ``out``.

    Bad options (the endpoint, a port in use, the real-time factor, certificates, the user's password) are
    refused before the output folder is made; anything that fails after leaves ``run_info.json`` at
    ``failed`` with what happened, never at ``running``."""
    from fishfmu.commands import run_inputs
    from fishfmu.cosim.build import checked
    from fishfmu.cosim.stop import stop_on_signals
    from fishfmu.output.atomic import write_run_info
    from fishfmu.output.run_folder import mark_running, prepare_out_dir, write_outputs
    from fishfmu.scenario.schema import load_scenario
    from fishfmu.session import register_output
    scenario_file = Path(scenario_file)
    problem = options_problem(endpoint, allow_remote, realtime, certificates)
    if problem:
        raise problem
    sc = load_scenario(scenario_file, overrides or {})
    with checked(sc, scenario_file) as c:
        line = LineServer(c, endpoint, allow_remote, realtime, user, certificates)
        try:
            problem = listen_problem(endpoint)
            if problem:
                raise InputError(problem, where="--endpoint")
            out_dir = prepare_out_dir(out, overwrite, run_inputs(scenario_file, sc, None), "serve")
        except BaseException:
            line.close()
            raise
        t0 = time.perf_counter()
        # a signal from here on only sets a flag: the server ends at its next look and the run is written
        with stop_on_signals() as stop:
            mark_running(out_dir, scenario_file)
            register_output(out_dir)
            writing = False
            try:
                line.start()
                if line.cosim is not None:  # else an FMU failed while the line was built: a failed run
                    asyncio.run(line.serve(on_ready, stop))
                # ended by the scenario's end or by a client's stop(): a complete run; by a signal: partial
                ended = line.state == "finished" or line.stop_requested.is_set()
                status = "failed" if line.error else "ok" if ended else "partial"
                result = line.result(status, time.perf_counter() - t0)
                writing = True  # write_outputs marks its own failure in run_info.json
                write_outputs(result, out_dir, report=report)
            except Exception as exc:
                if not writing:
                    with contextlib.suppress(OSError):
                        write_run_info(out_dir, "failed", scenario=str(scenario_file),
                                       error=f"{type(exc).__name__}: {exc}" if not isinstance(
                                           exc, (InputError, SimulationError)) else str(exc))
                raise
            finally:
                line.close()
    return ServeOutcome(result, out_dir, stop.exit_code if status == "partial" else None)


@dataclass(frozen=True)
class ServeOutcome:
    result: RunResult
    out_dir: Path
    stop_exit_code: int | None
