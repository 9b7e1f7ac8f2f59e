"""Who may do what on the served line: anonymous clients read; writes and method calls need a user whose role
allows them, unless a lab bench opens them to anyone on purpose (``--allow-anonymous-write``).

Users come from a TOML file (``--users FILE``), never a password on the command line::

    [[user]]
    name = "plc"
    role = "operator"          # operator: write the inputs, call every method; viewer: read only
    password = "scrypt$16384$8$1$<salt, base64>$<hash, base64>"   # made by `fishfmu hash-password`

Passwords are stored as scrypt hashes (``hashlib.scrypt``) and compared in constant time.  A user name or password
that does not match is refused a session (BadUserAccessDenied); a viewer's or an anonymous client's write or call
is refused (BadUserAccessDenied) by :class:`AccessRules`, asyncua's permission check before any service runs.
What a session reads of its own rights says the same (:class:`UserRights`): a viewer sees the inputs' UserAccessLevel
without write and the methods' UserExecutable false, an operator both as the nodes hold them.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole

from plant.errors import InputError

ROLES = {"viewer": frozenset(), "operator": frozenset({"write", "call"})}
"""What each role may do besides reading."""
_SCRYPT = (16384, 8, 1)
"""scrypt's cost n, block size r and parallelism p (the interactive-login parameters of its paper)."""
_WRITE = ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary)
_CALL = ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary)
_READ_TYPES = frozenset(ua.NodeId(t) for t in USER_TYPES) - {_WRITE, _CALL}


def hash_password(password: str, salt: bytes | None = None) -> str:
    """The stored form of ``password``: ``scrypt$n$r$p$salt$hash`` (base64)."""
    salt = salt if salt is not None else os.urandom(16)
    n, r, p = _SCRYPT
    digest = hashlib.scrypt(password.encode(), salt=salt, n=n, r=r, p=p, dklen=32)
    return f"scrypt${n}${r}${p}${base64.b64encode(salt).decode()}${base64.b64encode(digest).decode()}"


def password_matches(password: str, stored: str) -> bool:
    try:
        kind, n, r, p, salt, digest = stored.split("$")
        expected = base64.b64decode(digest, validate=True)
        got = hashlib.scrypt(password.encode(), salt=base64.b64decode(salt, validate=True), n=int(n), r=int(r),
                             p=int(p), dklen=len(expected))
    except (ValueError, TypeError):
        return False
    return kind == "scrypt" and hmac.compare_digest(got, expected)


@dataclass(frozen=True)
class Account:
    name: str
    role: str
    password: str
    """Its scrypt hash."""


class LineUser(User):
    """An asyncua session's user with its role on the line."""

    def __init__(self, name: str | None, line_role: str) -> None:
        super().__init__(role=UserRole.Anonymous if name is None else UserRole.User, name=name)
        self.line_role = line_role


def read_users(path: Path) -> dict[str, Account]:
    """The accounts of a users file (see the module docstring); bad input names the file and the entry."""
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as exc:
        raise InputError(f"cannot be read ({exc.strerror or exc})", file=path, where="--users") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"is not TOML ({exc})", file=path) from None
    entries = doc.get("user")
    if set(doc) - {"user"} or not isinstance(entries, list) or not entries:
        raise InputError("a users file holds [[user]] tables only, at least one", file=path)
    accounts: dict[str, Account] = {}
    for i, e in enumerate(entries):
        where = f"user[{i}]"
        if not isinstance(e, dict) or set(e) != {"name", "role", "password"}:
            raise InputError("needs exactly name, role and password (a hash from `fishfmu hash-password`)",
                             file=path, where=where)
        if not isinstance(e["name"], str) or not e["name"] or e["name"] in accounts:
            raise InputError("name must be a non-empty string, once in the file", file=path, where=f"{where}.name")
        if e["role"] not in ROLES:
            raise InputError(f"role must be one of {', '.join(ROLES)}", file=path, where=f"{where}.role")
        if not isinstance(e["password"], str) or not e["password"].startswith("scrypt$") or \
                len(e["password"].split("$")) != 6:
            raise InputError("password must be a hash made by `fishfmu hash-password` (scrypt$...), never the "
                             "password itself", file=path, where=f"{where}.password")
        accounts[e["name"]] = Account(e["name"], e["role"], e["password"])
    return accounts


class LineUsers:
    """asyncua's user manager: anonymous sessions (as ``anonymous_role``) and the accounts, by password."""

    def __init__(self, accounts: dict[str, Account], anonymous_role: str | None) -> None:
        self.accounts, self.anonymous_role = accounts, anonymous_role

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> Any:
        if username is None:
            return LineUser(None, self.anonymous_role) if self.anonymous_role is not None else None
        account = self.accounts.get(username)
        if account is None or password is None or not password_matches(password, account.password):
            return None
        return LineUser(account.name, account.role)


class AccessRules(PermissionRuleset):
    """asyncua's permission check of each request: reading for every session, writing and calling for a role that
    allows them."""

    def check_validity(self, user: Any, action_type_id: Any, body: Any) -> bool:
        if action_type_id in _READ_TYPES:
            return True
        allowed = ROLES.get(getattr(user, "line_role", "viewer"), frozenset())
        return (action_type_id == _WRITE and "write" in allowed) or (action_type_id == _CALL and "call" in allowed)


class UserRights:
    """The UserAccessLevel and UserExecutable a session reads, as its user has them: asyncua keeps one value per node
    (the operator's: the inputs writable, the methods executable) and reads it to every session; this listener of
    asyncua's PostRead callback takes write from a UserAccessLevel, and makes UserExecutable false, in what a session
    whose role does not allow it reads of the line's namespace ``namespace_index`` (writes and calls are refused by
    :class:`AccessRules` all the same).  Reads only: a subscription to those attributes gets the stored value."""

    def __init__(self, namespace_index: int) -> None:
        self.namespace_index = namespace_index

    def __call__(self, event: Any, dispatcher: Any) -> None:
        if not event.is_external:  # the server's own reads
            return
        allowed = ROLES.get(getattr(event.user, "line_role", "viewer"), frozenset())
        results = event.response_params
        for i, read in enumerate(event.request_params.NodesToRead):
            value = results[i].Value
            if read.NodeId.NamespaceIndex != self.namespace_index or value is None or value.Value is None:
                continue
            if read.AttributeId == ua.AttributeIds.UserAccessLevel and "write" not in allowed:
                level = value.Value & ~ua.AccessLevel.CurrentWrite.mask
                results[i] = ua.DataValue(ua.Variant(level, ua.VariantType.Byte))
            elif read.AttributeId == ua.AttributeIds.UserExecutable and "call" not in allowed:
                results[i] = ua.DataValue(ua.Variant(False, ua.VariantType.Boolean))
