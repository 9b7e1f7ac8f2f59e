"""``fishfmu serve`` against what a hostile user or a careless PLC does (issue 28).

The server steps the line in a worker thread: it answers reads, a second client, ``stop()`` and signals while a
long ``step(n)`` runs; bad options are refused before the output folder is made (exit 2 naming the option); a
write an input cannot take and a method called with bad arguments get an OPC UA status, not a traceback; every
plant output is in the address space, recorded or not; ``run`` refuses a scenario whose inputs a PLC writes.
"""

from __future__ import annotations

import asyncio
import json
import math
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

asyncua = pytest.importorskip("asyncua")
from asyncua import Client, ua  # noqa: E402

from plant.errors import InputError  # noqa: E402

from tests.test_serve import LAB, SERVED, SHORT, connect, free_port, make_certificate  # noqa: E402

RUN = [sys.executable, "-m", "fishfmu.cli"]


def serve(out: Path, *extra: str) -> tuple[subprocess.Popen, str]:
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    proc = subprocess.Popen([*RUN, "serve", str(SERVED), "--endpoint", url, "--out", str(out), *SHORT, *LAB, *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, url


def ended(proc: subprocess.Popen, within_s: float) -> tuple[str, str]:
    """The server's output once it has exited, which it must within ``within_s``."""
    try:
        return proc.communicate(timeout=within_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"the server did not exit within {within_s} s: {err[-2000:]}") from None


def node_of(client: Client, idx: int, name: str):  # noqa: ANN201
    return client.get_node(ua.NodeId(name, idx))


async def call(client: Client, idx: int, method: str, *args: ua.Variant):  # noqa: ANN201
    return await node_of(client, idx, "fishfmu").call_method(ua.QualifiedName(method, idx), *args)


async def status_of(coro) -> str:  # noqa: ANN001
    """The name of the OPC UA status a request was refused with ("Good" when it was not)."""
    try:
        await coro
    except ua.UaStatusCodeError as exc:
        return type(exc).__name__
    return "Good"


def info_of(out: Path) -> dict:
    return json.loads((out / "run_info.json").read_text())


# ---------------------------------------------------------------- run refuses what a PLC must write

def test_run_refuses_a_scenario_whose_inputs_a_plc_writes(tmp_path):
    from fishfmu import commands
    short = {"run.duration_s": 0.05, "fish.count": 1}  # today's code runs it: keep that short
    with pytest.raises(InputError, match="fishfmu serve") as err:
        commands.run(SERVED, tmp_path / "lib", short, report=False)
    assert err.value.where == "opcua.inputs" and "drive_c1.speed_setpoint" in str(err.value)
    with pytest.raises(InputError, match="fishfmu serve"):
        commands.run_seeds(SERVED, 2, tmp_path / "seeds", short, workers=1)
    with pytest.raises(InputError, match="fishfmu serve"):  # nor swept: every run would hold the start values
        commands.sweep(SERVED, {"run.seed": [1, 2]}, 1, tmp_path / "sweep", fixed=short)
    cli = subprocess.run([*RUN, "run", str(SERVED), "--out", str(tmp_path / "cli"), "--set", "run.duration_s=0.05",
                          "--no-report"], capture_output=True, text=True, timeout=120)
    assert cli.returncode == 2, cli.stderr
    assert "fishfmu serve" in cli.stderr and "opcua.inputs" in cli.stderr and "Traceback" not in cli.stderr
    assert len(cli.stderr.strip().splitlines()) == 1, cli.stderr
    assert not any((tmp_path / d).exists() for d in ("lib", "seeds", "cli", "sweep"))


# ---------------------------------------------------------------- start-up: bad options, before the folder

def _serve_in_process(out: Path, **options):  # noqa: ANN003, ANN202
    """serve_scenario as the CLI calls it; a server that starts anyway (today's code) is stopped at once."""
    from fishfmu.commands import serve as serve_scenario
    return serve_scenario(SERVED, out, {"fish.count": 1, "run.duration_s": 0.05}, report=False,
                          on_ready=lambda line: line.stop_requested.set(), **options)


@pytest.mark.parametrize("endpoint", ["opc.tcp://127.0.0.1:99999", "opc.tcp://127.0.0.1:-5",
                                      "opc.tcp://127.0.0.1:abc", "opc.tcp://127.0.0.1:0", "opc.tcp://127.0.0.1"])
def test_an_endpoint_without_a_usable_port_is_bad_input(tmp_path, endpoint):
    with pytest.raises(InputError) as err:
        _serve_in_process(tmp_path / "o", endpoint=endpoint)
    assert err.value.where == "--endpoint" and "port of 1 to 65535" in err.value.message
    assert not (tmp_path / "o").exists()


def test_a_port_in_use_is_bad_input_before_the_folder_and_never_leaves_it_running(tmp_path, monkeypatch):
    import fishfmu.serve
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        endpoint = f"opc.tcp://127.0.0.1:{taken.getsockname()[1]}"
        with pytest.raises(InputError) as err:
            _serve_in_process(tmp_path / "o", endpoint=endpoint)
        assert err.value.where == "--endpoint" and "in use" in err.value.message
        assert not (tmp_path / "o").exists()
        # taken between that check and the server's start (another server won the race): still bad input, and
        # the folder made by then says failed with why
        monkeypatch.setattr(fishfmu.serve, "listen_problem", lambda endpoint: None)
        with pytest.raises(InputError) as err:
            _serve_in_process(tmp_path / "race", endpoint=endpoint)
    assert err.value.where == "--endpoint" and "in use" in err.value.message
    info = info_of(tmp_path / "race")
    assert info["status"] == "failed" and "in use" in info["error"]


@pytest.mark.parametrize("factor", [0.0, -1.0, 1e-4, 1e4, math.nan, math.inf])
def test_a_real_time_factor_out_of_bounds_is_bad_input(tmp_path, factor):
    with pytest.raises(InputError) as err:
        _serve_in_process(tmp_path / "o", realtime=factor)
    assert err.value.where == "--realtime"
    assert not (tmp_path / "o").exists()


def test_the_command_line_says_which_option_in_one_line_with_exit_2(tmp_path):
    # --realtime 1e-300: today's server starts and sleeps through everything (hence the timeout)
    for option, value in (("--realtime", "1e-300"), ("--endpoint", "opc.tcp://127.0.0.1:abc")):
        cli = subprocess.run([*RUN, "serve", str(SERVED), option, value, "--out", str(tmp_path / "o"), *SHORT],
                             capture_output=True, text=True, timeout=60)
        assert cli.returncode == 2 and option in cli.stderr, (option, cli.stderr)
        assert "Traceback" not in cli.stderr and len(cli.stderr.strip().splitlines()) == 1, cli.stderr
        assert not (tmp_path / "o").exists()


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A server certificate and key, another key, and a folder with one trusted client certificate."""
    root = tmp_path_factory.mktemp("pki")
    trusted = root / "trusted"
    trusted.mkdir()

    async def make() -> dict[str, Path]:
        cert, key = await make_certificate(root, "server", "urn:fishfmu:server", True)
        client_cert, client_key = await make_certificate(trusted, "client", "urn:test:client", False)
        _, other_key = await make_certificate(root, "other", "urn:test:other", True)
        client_key.rename(root / "client.pem")  # the folder holds certificates only
        return {"cert": cert, "key": key, "other_key": other_key, "trusted": trusted}
    return asyncio.run(make())


def _garbage(path: Path, data: bytes = b"not a certificate\x00\xff") -> Path:
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("case", ["garbage certificate", "PEM garbage", "garbage key", "another certificate's key",
                                  "garbage in the trusted folder", "empty trusted folder", "encrypted key",
                                  "a folder as the certificate"])
def test_certificate_files_the_server_cannot_use_are_bad_input(tmp_path, pki, case):
    from cryptography.hazmat.primitives import serialization

    from fishfmu.serve import Certificates
    cert, key, trusted = pki["cert"], pki["key"], pki["trusted"]
    option = "--certificate"
    if case == "garbage certificate":
        cert = _garbage(tmp_path / "server.der")
    elif case == "PEM garbage":
        cert = _garbage(tmp_path / "server.pem", b"-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n")
    elif case == "a folder as the certificate":
        cert = tmp_path
    elif case == "garbage key":
        key, option = _garbage(tmp_path / "key.pem"), "--private-key"
    elif case == "another certificate's key":
        key, option = pki["other_key"], "--private-key"
    elif case == "encrypted key":
        loaded = serialization.load_pem_private_key(key.read_bytes(), password=None)
        key, option = tmp_path / "locked.pem", "--private-key"
        key.write_bytes(loaded.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                             serialization.BestAvailableEncryption(b"secret")))
    elif case == "garbage in the trusted folder":
        trusted, option = tmp_path / "trusted", "--trusted-clients"
        trusted.mkdir()
        (trusted / "client.der").write_bytes((pki["trusted"] / "client.der").read_bytes())
        _garbage(trusted / "notes.pem")
    elif case == "empty trusted folder":
        trusted, option = tmp_path / "empty", "--trusted-clients"
        trusted.mkdir()
    with pytest.raises(InputError) as err:
        _serve_in_process(tmp_path / "o", certificates=Certificates(cert, key, trusted))
    assert err.value.where == option, err.value
    assert not (tmp_path / "o").exists()


def test_usable_certificates_pass_the_check(pki):
    from fishfmu.serve import Certificates
    assert Certificates(pki["cert"], pki["key"], pki["trusted"]).problem() is None


# ---------------------------------------------------------------- the address space, writes, methods, reset

async def node_ids_under(node) -> set[str]:  # noqa: ANN001 - an asyncua Node
    """The node ids of the variables and methods held by ``node``'s objects, at any depth (not their properties)."""
    out = set()
    for child in await node.get_children():
        if await child.read_node_class() == ua.NodeClass.Object:
            out |= await node_ids_under(child)
        else:
            out.add(child.nodeid.Identifier)
    return out


async def hostile_plc(url: str, proc: subprocess.Popen) -> dict:
    client = await connect(url, proc)
    seen: dict = {}
    try:
        idx = await client.get_namespace_index("urn:fishfmu")
        folder = node_of(client, idx, "fishfmu")
        seen["names"] = await node_ids_under(folder)
        sp1, sp2 = node_of(client, idx, "drive_c1.speed_setpoint"), node_of(client, idx, "drive_c2.speed_setpoint")
        double = ua.VariantType.Double
        seen["writes"] = {
            "array": await status_of(sp1.write_value(ua.Variant([1.0, 1.0], double))),
            "nan": await status_of(sp1.write_value(ua.Variant(math.nan, double))),
            "beyond its max": await status_of(sp1.write_value(ua.Variant(9.0, double))),
            "float": await status_of(sp1.write_value(ua.Variant(1.0, ua.VariantType.Float))),
        }
        seen["after refusals"] = await sp1.read_value()
        i32 = ua.VariantType.Int32
        seen["step"] = {
            "no argument": await status_of(call(client, idx, "step")),
            "a string": await status_of(call(client, idx, "step", ua.Variant("abc", ua.VariantType.String))),
            "negative": await status_of(call(client, idx, "step", ua.Variant(-1, i32))),
            "a double": await status_of(call(client, idx, "step", ua.Variant(1.5, double))),
            "an array": await status_of(call(client, idx, "step", ua.Variant([1, 2], i32))),
            "two": await status_of(call(client, idx, "step", ua.Variant(1, i32), ua.Variant(1, i32))),
            "stop with one": await status_of(call(client, idx, "stop", ua.Variant(1, i32))),
        }
        # a good write after the refused ones is used
        await sp1.write_value(ua.Variant(1.0, double))
        seen["t"] = await call(client, idx, "step", ua.Variant(50, i32))
        seen["belt_speed"] = await node_of(client, idx, "drive_c1.belt_speed").read_value()
        seen["eyes"] = [await node_of(client, idx, f"plant.pe_c{i}.blocked").read_value() for i in range(1, 5)]
        seen["counts"] = [await node_of(client, idx, f"fishfmu.fish_{s}").read_value()
                          for s in ("waiting", "on_line", "left")]
        # reset() discards the run and what was written in it
        seen["t_reset"] = await call(client, idx, "reset")
        await sp2.write_value(ua.Variant(0.5, double))
        await call(client, idx, "step", ua.Variant(5, i32))
        # stop() from a second client ends a long step(n) of the first within a step, not at its end
        other = await connect(url, proc)
        long_step = asyncio.create_task(call(client, idx, "step", ua.Variant(1_000_000, i32)))
        await asyncio.sleep(0.5)
        t0 = time.monotonic()
        other_idx = await other.get_namespace_index("urn:fishfmu")
        await call(other, other_idx, "stop")
        seen["stop_s"] = time.monotonic() - t0
        seen["long_t"] = await asyncio.wait_for(long_step, 10)
        seen["long_step_s"] = time.monotonic() - t0
        await other.disconnect()
    finally:
        await client.disconnect()
    return seen


def test_a_hostile_plc_gets_statuses_and_the_plants_sensors_unrecorded(tmp_path):
    # nothing of the plant recorded: its outputs are served all the same (a PLC always needs its photo-eyes)
    proc, url = serve(tmp_path / "o", "--set", "record.variables=[]")
    seen = asyncio.run(hostile_plc(url, proc))
    out, err = ended(proc, 60)
    assert {f"plant.pe_c{i}.blocked" for i in range(1, 5)} <= seen["names"], seen["names"]
    assert {f"plant.c{i}.{s}" for i in range(1, 5) for s in ("speed", "load_force", "load_mass")} <= seen["names"]
    assert {"fishfmu.fish_waiting", "fishfmu.fish_on_line", "fishfmu.fish_left"} <= seen["names"]
    assert seen["writes"] == {"array": "BadTypeMismatch", "nan": "BadOutOfRange", "beyond its max": "BadOutOfRange",
                              "float": "BadTypeMismatch"}
    assert seen["after refusals"] == 0.0  # nothing of a refused write was kept
    assert seen["step"] == {"no argument": "BadArgumentsMissing", "a string": "BadInvalidArgument",
                            "negative": "BadInvalidArgument", "a double": "BadInvalidArgument",
                            "an array": "BadInvalidArgument", "two": "BadTooManyArguments",
                            "stop with one": "BadTooManyArguments"}
    assert seen["t"] == pytest.approx(0.5) and seen["belt_speed"] > 0.1  # the drive follows the good write
    assert seen["eyes"] == [False] * 4 and sum(seen["counts"]) == 4
    assert seen["t_reset"] == 0.0
    assert seen["stop_s"] < 2.0 and seen["long_step_s"] < 3.0 and 0.05 < seen["long_t"] < 20.0, seen
    assert "Traceback" not in err and "BadUnexpectedError" not in err, err
    info = info_of(tmp_path / "o")
    # only the run after the reset is written, with only its writes
    assert info["served"]["writes"] == [{"t_s": 0.0, "input": "drive_c2.speed_setpoint", "value": 0.5}]
    assert info["served"]["resets"] == 1 and info["served"]["ended"] == "stop() called by a client"
    assert info["t_end_s"] == pytest.approx(seen["long_t"])


# ---------------------------------------------------------------- answering while it steps; signals

async def read_while_stepping(url: str, proc: subprocess.Popen) -> dict:
    stepper, reader = await connect(url, proc), await connect(url, proc)
    seen: dict = {"reads": []}
    idx = await stepper.get_namespace_index("urn:fishfmu")
    t_node = node_of(reader, idx, "fishfmu.time_s")
    long_step = asyncio.create_task(call(stepper, idx, "step", ua.Variant(1_000_000, ua.VariantType.Int32)))
    try:
        await asyncio.sleep(0.3)
        for _ in range(3):  # each read answered at once, and the time moving on
            t0 = time.monotonic()
            seen["reads"].append((await asyncio.wait_for(t_node.read_value(), 2.0), time.monotonic() - t0))
            await asyncio.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        seen["sigterm_at"] = time.monotonic()
    finally:
        long_step.cancel()
        for c in (stepper, reader):
            try:
                await asyncio.wait_for(c.disconnect(), 5)
            except (OSError, asyncio.TimeoutError, ua.UaError):
                pass  # the server is gone
    return seen


def test_the_server_answers_while_a_long_step_runs_and_a_signal_ends_it_at_once(tmp_path):
    proc, url = serve(tmp_path / "o", "--set", "run.duration_s=600")
    seen = asyncio.run(read_while_stepping(url, proc))
    out, err = ended(proc, 5)
    gone_s = time.monotonic() - seen["sigterm_at"]
    times = [t for t, _ in seen["reads"]]
    assert all(latency < 1.0 for _, latency in seen["reads"]), seen
    assert 0.0 < times[0] < times[1] < times[2], seen  # the step's progress is published while it runs
    assert proc.returncode == 143 and gone_s < 5, (gone_s, err)
    info = info_of(tmp_path / "o")
    assert info["status"] == "partial" and info["served"]["ended"] == "a signal"
    assert times[-1] <= info["t_end_s"] < 600
    assert "Traceback" not in err


async def slow_real_time(url: str, proc: subprocess.Popen, end: str) -> dict:
    client = await connect(url, proc)
    idx = await client.get_namespace_index("urn:fishfmu")
    seen = {"step": await status_of(call(client, idx, "step", ua.Variant(1, ua.VariantType.Int32)))}
    await asyncio.sleep(0.3)  # in the wait for the second step, due 10 s after the first
    seen["t0"] = time.monotonic()
    if end == "stop":
        await call(client, idx, "stop")
    else:
        proc.send_signal(signal.SIGTERM)
    try:
        await asyncio.wait_for(client.disconnect(), 5)
    except (OSError, asyncio.TimeoutError, ua.UaError):
        pass
    return seen


@pytest.mark.parametrize("end", ["stop", "SIGTERM"])
def test_slow_real_time_wakes_for_stop_and_signals(tmp_path, end):
    proc, url = serve(tmp_path / "o", "--realtime", "0.001")
    seen = asyncio.run(slow_real_time(url, proc, end))
    out, err = ended(proc, 5)
    assert time.monotonic() - seen["t0"] < 5
    assert seen["step"] == "BadInvalidState" and "Traceback" not in err, err  # the wall clock steps the line
    info = info_of(tmp_path / "o")
    if end == "stop":
        assert proc.returncode == 1, err  # a complete run stopped at 0.01 s: the scenario's bounds are missed
        assert info["status"] == "ok" and info["served"]["ended"] == "stop() called by a client"
    else:
        assert proc.returncode == 143 and info["status"] == "partial", err
    assert info["t_end_s"] == pytest.approx(0.01)
