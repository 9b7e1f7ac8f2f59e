"""Who may do what on the served line (issue 42): anonymous clients read only by default; writes and method calls
need a user (from a --users file, passwords hashed) whose role allows them, or --allow-anonymous-write on a lab
bench; a users file that is not one is bad input naming the file and the entry."""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("asyncua")
from asyncua import Client, ua  # noqa: E402

from fishfmu.serve.access import hash_password, password_matches  # noqa: E402
from tests.test_serve import SERVED, connect, free_port  # noqa: E402
from tests.test_serve_model import users_file  # noqa: E402

SHORT = ["--set", "fish.count=1", "--set", "run.duration_s=1", "--no-report"]


async def _session(url: str, creds: tuple[str, str] | None) -> dict | str:
    """What a client with ``creds`` (None: anonymous) gets: a read, what it reads of its rights (an input's
    UserAccessLevel has write, step's UserExecutable), a write of an input and a step."""
    client = Client(url)
    if creds:
        client.set_user(creds[0])
        client.set_password(creds[1])
    try:
        await client.connect()
    except ua.UaStatusCodeError as exc:
        return type(exc).__name__
    try:
        idx = await client.get_namespace_index("urn:fishfmu")
        seen: dict = {"read": await client.get_node(ua.NodeId("fishfmu.run_state", idx)).read_value()}
        level = await client.get_node(ua.NodeId("drive_c1.speed_setpoint", idx)).read_attribute(
            ua.AttributeIds.UserAccessLevel)
        seen["writable"] = bool(level.Value.Value & ua.AccessLevel.CurrentWrite.mask)
        step = await client.get_node(ua.NodeId("fishfmu", idx)).get_child(f"{idx}:step")
        seen["executable"] = (await step.read_attribute(ua.AttributeIds.UserExecutable)).Value.Value
        try:
            await client.get_node(ua.NodeId("drive_c1.speed_setpoint", idx)).write_value(
                ua.Variant(0.5, ua.VariantType.Double))
            seen["write"] = "Good"
        except ua.UaStatusCodeError as exc:
            seen["write"] = type(exc).__name__
        try:
            await client.get_node(ua.NodeId("fishfmu", idx)).call_method(ua.QualifiedName("step", idx),
                                                                        ua.Variant(1, ua.VariantType.Int32))
            seen["call"] = "Good"
        except ua.UaStatusCodeError as exc:
            seen["call"] = type(exc).__name__
        return seen
    finally:
        await client.disconnect()


async def _sessions(url: str, proc: subprocess.Popen, who: dict, stopper: tuple[str, str] | None) -> dict:
    await (await connect(url, proc)).disconnect()
    seen = {label: await _session(url, creds) for label, creds in who.items()}
    client = Client(url)
    if stopper:
        client.set_user(stopper[0])
        client.set_password(stopper[1])
    await client.connect()
    idx = await client.get_namespace_index("urn:fishfmu")
    await client.get_node(ua.NodeId("fishfmu", idx)).call_method(ua.QualifiedName("stop", idx))
    return seen


def _serve(tmp_path: Path, *extra: str) -> tuple[subprocess.Popen, str]:
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "fishfmu.cli", "serve", str(SERVED), "--endpoint", url, "--out",
                             str(tmp_path / "o"), *SHORT, *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    return proc, url


def test_anonymous_reads_only_and_each_user_does_what_its_role_allows(tmp_path):
    users = users_file(tmp_path, {"plc": ("operator", "plc pass"), "hmi": ("viewer", "hmi pass")})
    proc, url = _serve(tmp_path, "--users", str(users))
    who = {"anonymous": None, "operator": ("plc", "plc pass"), "viewer": ("hmi", "hmi pass"),
           "wrong password": ("plc", "hmi pass"), "unknown user": ("root", "plc pass")}
    seen = asyncio.run(_sessions(url, proc, who, ("plc", "plc pass")))
    out, err = proc.communicate(timeout=120)
    denied = {"read": "running", "writable": False, "executable": False, "write": "BadUserAccessDenied",
              "call": "BadUserAccessDenied"}
    allowed = {"read": "running", "writable": True, "executable": True, "write": "Good", "call": "Good"}
    assert seen == {"anonymous": denied, "operator": allowed,
                    "viewer": denied, "wrong password": "BadUserAccessDenied",
                    "unknown user": "BadUserAccessDenied"}
    assert "Traceback" not in err and "plc pass" not in out + err, err
    assert "anonymous clients: read only" in out


def test_a_lab_bench_lets_anonymous_clients_write_only_when_told(tmp_path):
    proc, url = _serve(tmp_path, "--allow-anonymous-write")
    seen = asyncio.run(_sessions(url, proc, {"anonymous": None}, None))
    proc.communicate(timeout=120)
    assert seen == {"anonymous": {"read": "running", "writable": True, "executable": True, "write": "Good",
                                  "call": "Good"}}


@pytest.mark.parametrize("case", ["plain password", "unknown role", "not TOML", "twice the same name"])
def test_a_users_file_that_is_not_one_is_bad_input_naming_the_entry(tmp_path, case):
    hashed = hash_password("x")
    text = {"plain password": '[[user]]\nname = "plc"\nrole = "operator"\npassword = "hunter2"\n',
            "unknown role": f'[[user]]\nname = "plc"\nrole = "god"\npassword = "{hashed}"\n',
            "not TOML": "[[user]\nname = plc\n",
            "twice the same name": (f'[[user]]\nname = "plc"\nrole = "viewer"\npassword = "{hashed}"\n' * 2)}[case]
    users = tmp_path / "users.toml"
    users.write_text(text)
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "serve", str(SERVED), "--users", str(users), "--out",
                          str(tmp_path / "o"), *SHORT], capture_output=True, text=True, timeout=120)
    where = {"plain password": "user[0].password", "unknown role": "user[0].role", "not TOML": "users.toml",
             "twice the same name": "user[1].name"}[case]
    assert cli.returncode == 2 and where in cli.stderr and len(cli.stderr.strip().splitlines()) == 1, cli.stderr
    assert "hunter2" not in cli.stderr and not (tmp_path / "o").exists()


def test_a_stored_password_is_a_salted_hash_that_only_its_password_matches():
    a, b = hash_password("plc pass"), hash_password("plc pass")
    assert a != b and "plc pass" not in a  # salted: the same password stored twice differs
    assert password_matches("plc pass", a) and password_matches("plc pass", b)
    assert not password_matches("plc pas", a) and not password_matches("plc pass", a[:-4] + "AAA=")


async def _secure_clients(url: str, proc: subprocess.Popen, server_cert: Path, clients: dict) -> dict:
    """Per client (label: (cert, key, its application URI, policy class)): the time it read, or how it was refused;
    the last one stops the run."""
    await asyncio.sleep(0)
    out = {}
    for label, (cert, key, uri, policy) in clients.items():
        for _ in range(400):  # the server is still building the line: try again until it listens
            client = Client(url)
            client.application_uri = uri
            await client.set_security(policy, str(cert), str(key), server_certificate=str(server_cert))
            try:
                await client.connect()
            except (ConnectionError, OSError) as exc:
                if proc.poll() is not None or out:  # the server is up (a client got in): this is a refusal
                    out[label] = type(exc).__name__
                    break
                await asyncio.sleep(0.3)
                continue
            except (ua.UaError, asyncio.TimeoutError) as exc:
                out[label] = type(exc).__name__
                break
            idx = await client.get_namespace_index("urn:fishfmu")
            out[label] = await client.get_node(ua.NodeId("fishfmu.time_s", idx)).read_value()
            if label == "last":
                await client.get_node(ua.NodeId("fishfmu", idx)).call_method(ua.QualifiedName("stop", idx))
            with contextlib.suppress(ConnectionError, OSError, asyncio.TimeoutError):
                await client.disconnect()
            break
    return out


def test_pki_makes_the_servers_certificate_on_first_use_and_admits_only_trusted_clients(tmp_path):
    from asyncua.crypto.security_policies import SecurityPolicyAes256Sha256RsaPss, SecurityPolicyBasic256Sha256

    from tests.test_serve import make_certificate
    pki = tmp_path / "pki"
    first = subprocess.run([sys.executable, "-m", "fishfmu.cli", "serve", str(SERVED), "--pki", str(pki), "--out",
                            str(tmp_path / "o"), *SHORT], capture_output=True, text=True, timeout=120)
    # first use: the server's certificate is made; no client is trusted yet, which is bad input saying where to put one
    assert first.returncode == 2 and str(pki / "trusted") in first.stderr, first.stderr
    assert len(first.stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()
    server_cert = pki / "own" / "server_cert.der"
    made = server_cert.read_bytes()
    keys = tmp_path / "keys"
    keys.mkdir()
    trusted = asyncio.run(make_certificate(keys, "plc", "urn:test:trusted", False))
    (pki / "trusted" / "plc.der").write_bytes(trusted[0].read_bytes())
    untrusted = asyncio.run(make_certificate(keys, "intruder", "urn:test:untrusted", False))
    proc, url = _serve(tmp_path, "--pki", str(pki), "--allow-anonymous-write")
    try:
        seen = asyncio.run(_secure_clients(url, proc, server_cert, {
            "trusted": (*trusted, "urn:test:trusted", SecurityPolicyAes256Sha256RsaPss),
            "untrusted": (*untrusted, "urn:test:untrusted", SecurityPolicyBasic256Sha256),
            "last": (*trusted, "urn:test:trusted", SecurityPolicyBasic256Sha256)}))
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()  # a server the last client failed to stop must not outlive the test
        proc.wait()
    assert seen == {"trusted": 0.0, "untrusted": "BadCertificateUntrusted", "last": 0.0}, (seen, err)
    assert server_cert.read_bytes() == made  # made once, on first use
    # the untrusted certificate refused in one line each, no traceback
    assert "Traceback" not in err and "Not trusted certificate used" in err, err


def test_pki_never_writes_into_a_folder_fishfmu_did_not_make(tmp_path):
    mine = tmp_path / "certs"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "serve", str(SERVED), "--pki", str(mine), "--out",
                          str(tmp_path / "o"), *SHORT], capture_output=True, text=True, timeout=120)
    assert cli.returncode == 2 and "--pki" in cli.stderr and len(cli.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
