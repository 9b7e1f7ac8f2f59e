"""The server's certificate made on first use, in a folder fishfmu owns (``fishfmu serve --pki DIR``).

``DIR/own/server_cert.der`` and ``DIR/own/server_key.pem``: a self-signed certificate for the application URI
``urn:fishfmu:server`` (and this host's name), made when the folder is new, renewed by asyncua's helper when it is
no longer valid; ``DIR/trusted/``: the client certificates that may connect (a PLC's, copied there by its
integrator).  The folder carries a marker file; a folder without it is not fishfmu's and is never written into.
"""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

from cryptography.x509.oid import ExtendedKeyUsageOID

from plant.errors import InputError

from fishfmu.serve.options import Certificates

MARKER = ".fishfmu-pki"


def pki_certificates(folder: Path, application_uri: str) -> Certificates:
    """The certificates of the PKI folder ``folder``, the server's made if missing (see the module docstring)."""
    marker = folder / MARKER
    if folder.exists() and not marker.is_file():
        raise InputError(f"'{folder}' exists and was not made by fishfmu serve --pki; refusing to write into it "
                         "(choose a new folder)", where="--pki")
    own, trusted = folder / "own", folder / "trusted"
    try:
        own.mkdir(parents=True, exist_ok=True)
        trusted.mkdir(exist_ok=True)
        marker.write_text("made by fishfmu serve --pki: the server's certificate (own/) and the trusted client "
                          "certificates (trusted/)\n")
        # deferred: asyncua's helper (and asyncua) only when a server is made
        from asyncua.crypto.cert_gen import setup_self_signed_certificate
        cert, key = own / "server_cert.der", own / "server_key.pem"
        asyncio.run(setup_self_signed_certificate(key, cert, application_uri, socket.gethostname(),
                                                  [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
                                                  {"commonName": "fishfmu serve", "organizationName": "fishfmu"}))
    except OSError as exc:
        raise InputError(f"cannot write the server's certificate into '{folder}' ({exc.strerror or exc})",
                         where="--pki") from None
    if not any(f.is_file() for f in trusted.iterdir()):
        raise InputError(f"'{trusted}' holds no client certificate yet: copy each client's certificate (DER, or PEM "
                         f"named *.pem) there; give the clients the server's, '{cert}'", where="--pki")
    return Certificates(cert, key, trusted)
