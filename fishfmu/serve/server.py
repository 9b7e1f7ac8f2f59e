"""The asyncua server of ``fishfmu serve``: its endpoint, identity and security, and asyncua's messages.

Security: the endpoint must be on the loopback interface unless ``allow_remote`` is given (checked in
:mod:`fishfmu.serve.options`).  With a user (the password from the environment variable
``FISHFMU_OPCUA_PASSWORD``, never a command-line argument) anonymous sessions are refused and only that user may
connect.  Without certificates the connection is unencrypted (the NoSecurity policy: a password crosses the
network in plain text).  With certificates (the server's certificate and private key, and a folder of trusted
client certificates) the server offers only Basic256Sha256 with SignAndEncrypt and accepts only clients whose
certificate is in that folder.
"""

from __future__ import annotations

import hmac
from datetime import datetime, timezone
from importlib.metadata import version as package_version
from pathlib import Path
import logging
from typing import Any

from asyncua import Server, ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

import fishfmu
from plant.errors import InputError, one_line

from fishfmu.serve.options import Certificates, host_port, listen_error

APPLICATION_URI = "urn:fishfmu:server"
"""The server's application URI: a server certificate names it (subjectAltName URI) for clients that check."""


async def make_server(endpoint: str, user: str | None, password: str | None,
                      certificates: Certificates | None) -> Server:
    """An asyncua server for ``endpoint`` (not started): only ``user`` may connect when given, with
    ``certificates`` only Basic256Sha256 SignAndEncrypt for the trusted clients, else NoSecurity."""
    quiet_asyncua()
    server = Server(user_manager=OneUser(user, password) if user else None)
    await server.init()
    if user:  # no anonymous sessions: only the named user
        server.set_identity_tokens([ua.UserNameIdentityToken])
    server.set_endpoint(endpoint)
    server.set_server_name("fishfmu line")
    await server.set_application_uri(APPLICATION_URI)
    await set_build_info(server)
    if certificates is None:
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    else:
        c = certificates
        await server.load_certificate(str(c.certificate))
        await server.load_private_key(str(c.private_key))
        server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
        store = TrustStore([c.trusted_clients], [])
        await store.load()
        validator = CertificateValidator(CertificateValidatorOptions.TRUSTED_VALIDATION
                                         | CertificateValidatorOptions.PEER_CLIENT, store)
        server.set_certificate_validator(validator.validate)
    return server


async def set_build_info(server: Server) -> None:
    """The server's BuildInfo names fishfmu and its installed version (not asyncua's defaults); the build date is
    when this copy of fishfmu was installed (its package file's time)."""
    version = package_version("fishfmu")
    await server.set_build_info(product_uri="urn:fishfmu", manufacturer_name="fishfmu",
                                product_name="fishfmu serve", software_version=version, build_number=version,
                                build_date=datetime.fromtimestamp(Path(fishfmu.__file__).stat().st_mtime, timezone.utc))


async def start_server(server: Server, endpoint: str) -> None:
    """Start listening; a port taken since it was checked is bad input naming --endpoint (no traceback)."""
    logger = logging.getLogger("asyncua")
    level, logger.level = logger.level, logging.CRITICAL + 1  # its traceback of a failed start: ours says it
    try:
        await server.start()
    except OSError as exc:
        host, port = host_port(endpoint)
        raise InputError(listen_error(host, port, exc), where="--endpoint") from None
    finally:
        logger.setLevel(level)


def quiet_asyncua() -> None:
    """asyncua's errors as one line each on stderr, without tracebacks (a client's bad request is not fishfmu's
    bug); its warnings (a NoSecurity endpoint has no signing policy: what --allow-remote says) not at all."""
    logger = logging.getLogger("asyncua")
    logger.setLevel(logging.ERROR)
    if not any(isinstance(h.formatter, OneLine) for h in logger.handlers):
        handler = logging.StreamHandler()
        handler.setFormatter(OneLine())
        logger.addHandler(handler)
        logger.propagate = False


class OneLine(logging.Formatter):
    """A log record as one line: ``opcua: <message> (<exception>)``."""

    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        exc = record.exc_info[1] if record.exc_info else None
        if exc is not None:
            text += f" ({type(exc).__name__}: {exc})"
        return one_line(f"opcua: {text}")


class OneUser:
    """asyncua's user manager for one named user with a password (compared in constant time)."""

    def __init__(self, name: str, password: str) -> None:
        self.name, self.password = name, password

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> Any:
        if username == self.name and password is not None and hmac.compare_digest(password.encode(),
                                                                                   self.password.encode()):
            return User(role=UserRole.User, name=username)
        return None
