"""The asyncua server of ``fishfmu serve``: its endpoint, identity and security, and asyncua's messages.

Security: the endpoint must be on the loopback interface unless ``allow_remote`` is given (checked in
:mod:`fishfmu.serve.options`).  Who may connect and what each may do is :mod:`fishfmu.serve.access`'s: anonymous
sessions read, users with a role write and call methods.  Without certificates the connection is unencrypted (the
NoSecurity policy: a password crosses the network in plain text).  With certificates (the server's certificate and
private key, and a folder of trusted client certificates) the server offers Basic256Sha256, Aes128Sha256RsaOaep
and Aes256Sha256RsaPss, each Sign or SignAndEncrypt, and accepts only clients whose certificate is in that folder.
"""

from __future__ import annotations

from datetime import datetime, timezone
from importlib.metadata import version as package_version
from pathlib import Path
import logging
from typing import Any

from asyncua import Server, ua
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

import fishfmu
from plant.errors import InputError, one_line

from fishfmu.serve.access import AccessRules, LineUsers
from fishfmu.serve.options import Certificates, host_port, listen_error

APPLICATION_URI = "urn:fishfmu:server"
"""The server's application URI: a server certificate names it (subjectAltName URI) for clients that check."""


SECURE_POLICIES = [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt, ua.SecurityPolicyType.Basic256Sha256_Sign,
                   ua.SecurityPolicyType.Aes128Sha256RsaOaep_SignAndEncrypt,
                   ua.SecurityPolicyType.Aes128Sha256RsaOaep_Sign,
                   ua.SecurityPolicyType.Aes256Sha256RsaPss_SignAndEncrypt, ua.SecurityPolicyType.Aes256Sha256RsaPss_Sign]
"""The policies offered with certificates: those current PLCs and clients use (OPC UA 1.04/1.05), no deprecated
Basic128Rsa15/Basic256 and no NoSecurity."""


async def make_server(endpoint: str, users: LineUsers, certificates: Certificates | None) -> Server:
    """An asyncua server for ``endpoint`` (not started): sessions as ``users`` allows them (anonymous ones only
    when it has an anonymous role), each request checked by :class:`~fishfmu.serve.access.AccessRules`; with
    ``certificates`` the secure policies of :data:`SECURE_POLICIES` for the trusted clients, else NoSecurity."""
    quiet_asyncua()
    server = Server(user_manager=users)
    await server.init()
    server.set_identity_tokens([ua.UserNameIdentityToken] if users.anonymous_role is None else
                               [ua.AnonymousIdentityToken, ua.UserNameIdentityToken])
    server.set_endpoint(endpoint)
    server.set_server_name("fishfmu line")
    await server.set_application_uri(APPLICATION_URI)
    await set_build_info(server)
    if certificates is None:
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity], permission_ruleset=AccessRules())
    else:
        c = certificates
        await server.load_certificate(str(c.certificate))
        await server.load_private_key(str(c.private_key))
        server.set_security_policy(SECURE_POLICIES, permission_ruleset=AccessRules())
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
    bug); its warnings (a NoSecurity endpoint has no signing policy: what --allow-remote says) not at all.  Its
    trust store logs under ``asyncuagds`` (an untrusted client certificate, with a traceback): one line too."""
    for name in ("asyncua", "asyncuagds"):
        logger = logging.getLogger(name)
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
