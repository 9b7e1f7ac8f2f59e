"""What ``fishfmu serve`` is given besides the scenario, checked before anything starts: where to listen (the
endpoint, the port free), how fast (the real-time factor) and with which certificates.

Each check returns what is wrong as one line (the option it names is the caller's); :func:`options_problem` gives
the first as the :class:`~plant.errors.InputError` to raise, before the scenario is read.
"""

from __future__ import annotations

import errno
import ipaddress
import math
import re
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlparse


from plant.errors import InputError

DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840"
PASSWORD_ENV = "FISHFMU_OPCUA_PASSWORD"
REALTIME_RANGE = (1e-3, 1e3)
"""Real-time factors served: x0.001 is one 10 ms step per 10 s of wall time, x1000 more than any line keeps up with."""
MAX_CERTIFICATE_BYTES = 1 << 20
"""A certificate or key file larger than this is not one (refused before it is read)."""


def host_port(endpoint: str) -> tuple[str, int] | None:
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
    where = host_port(endpoint)
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


def modbus_host_port(where: str) -> tuple[str, int] | None:
    """The host and port of a Modbus TCP ``HOST:PORT``, or None when it is not one."""
    return host_port(f"opc.tcp://{where}")


def modbus_problem(where: str, allow_remote: bool, what: str = "Modbus TCP") -> str | None:
    """Why the Modbus server (or ``what`` else listens at a ``HOST:PORT``: the live view) must not listen at
    ``where``, or None (the rules of the OPC UA endpoint; a port below 1024, Modbus's 502, needs privileges)."""
    if modbus_host_port(where) is None:
        return f"'{where}' is not HOST:PORT with a port of 1 to 65535 ({what}: a port below 1024 needs privileges)"
    problem = endpoint_problem(f"opc.tcp://{where}", allow_remote)
    return problem or listen_problem(f"opc.tcp://{where}")


def listen_problem(endpoint: str) -> str | None:
    """Why nothing can listen at ``endpoint`` now (the port taken, the address not this machine's), or None.
    Binds each address as asyncio's server will (SO_REUSEADDR) and lets it go again."""
    host, port = host_port(endpoint)
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
                    return listen_error(host, port, exc)
                unavailable = exc  # asyncio skips an address family the machine has not enabled, so do we
                continue
            bound += 1
    return listen_error(host, port, unavailable) if not bound and unavailable is not None else None


def listen_error(host: str, port: int, exc: OSError) -> str:
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
        from cryptography.hazmat.primitives.asymmetric import rsa  # see read_crypto
        cert = read_crypto(self.certificate, "certificate")
        if isinstance(cert, str):
            return "--certificate", cert
        key = read_crypto(self.private_key, "private key")
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
            loaded = read_crypto(f, "certificate")
            if isinstance(loaded, str):
                return "--trusted-clients", f"{loaded}; the folder holds only client certificates"
        if not files:
            return "--trusted-clients", (f"'{folder}' holds no certificate (a file named *.der or *.pem): no client "
                                         "could connect")
        return None


def read_crypto(path: Path, what: str) -> Any:
    """The certificate or private key in ``path``, or what is wrong with the file (a str)."""
    # cryptography imported here: every fishfmu command imports this module (its defaults), and only serving with
    # certificates reads one (about 25 ms a process, -X importtime)
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
