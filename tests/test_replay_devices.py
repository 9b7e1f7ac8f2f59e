"""The replay draws a line's actuated devices (``[[line.devices]]``) moving as recorded: a reject gate on a two-belt
line, closed for its first second and then opened (poses.npz ``device_position``); a record without device positions
(a line without devices, an older poses.npz) still makes a page."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from plant.contract.devices import device_shapes
from plant.contract.line import Device
from plant.contract.measured import read_dataset
from plant.errors import InputError

from fishfmu import commands
from fishfmu.output.replay import build_scene, read_header, read_poses, unpack, write_replay

from tests.chromium import CHROMIUM, Browser

needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(), reason=f"no {CHROMIUM}: `apt-get install chromium`")

FLAP_M = 0.35
OPEN_AT_S = 1.0

GATE_LINE = f"""
[run]
name = "gate"
duration_s = 2.2
seed = 1
comm_step_s = 0.01

[line]
guide_width_m = 0.5

[[line.conveyors]]
id = "c1"
x_start_m = 0.0
length_m = 1.5
width_m = 0.5
z_top_m = 0.0

[[line.conveyors]]
id = "c2"
x_start_m = 1.9
length_m = 1.0
width_m = 0.5
z_top_m = -0.02

[[line.photoeyes]]
id = "pe1"
x_m = 1.4
z_m = 0.015

[[line.devices]]
id = "gate"
kind = "gate"
x_m = 1.5
length_m = {FLAP_M}
stroke_s = 0.4

[fish]
count = 1
first_drop_s = 0.3

[wiring]
inputs = {{ "plant.c1.speed" = 0.5, "plant.c2.speed" = 0.5, "plant.gate.command" = false }}

[[event]]
t_s = {OPEN_AT_S}
target = "plant.gate.command"
action = "override"
value = true

[kpi]
infeed_photoeye = "pe1"
outfeed_photoeye = "pe1"
"""


@pytest.fixture(scope="module")
def gate_run(tmp_path_factory) -> Path:
    """A 2.2 s run of one fish with the gate closed until 1 s, then open (fully by 1.4 s), recorded for the replay."""
    folder = tmp_path_factory.mktemp("gate")
    (folder / "gate.toml").write_text(GATE_LINE)
    done = commands.run(folder / "gate.toml", folder / "out", report=False, replay=True)
    assert done.result.status == "ok" and done.replay is not None
    return done.out_dir


@pytest.fixture(scope="module")
def poses(gate_run) -> dict[str, np.ndarray]:
    with np.load(gate_run / "poses.npz") as npz:
        return {k: npz[k] for k in npz.files}


def without_devices(poses: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: v for k, v in poses.items() if not k.startswith("device_")}


# ------------------------------------------------------------------------------- Python side
def test_the_page_holds_each_devices_shape_motion_and_recorded_positions(gate_run, poses):
    header, blob = read_header(gate_run / "replay.html")
    line = read_dataset(gate_run / "run").line
    [shape] = device_shapes(line)
    [gate] = header["devices"]
    assert (gate["id"], gate["kind"], gate["rotates"]) == ("gate", "gate", True)
    assert gate["origin_m"] == pytest.approx(shape.origin_m.tolist()) and gate["axis"] == shape.axis.tolist()
    assert gate["travel"] == pytest.approx(shape.travel, abs=1e-8)
    corners = shape.points_m[shape.triangles].reshape(-1)
    assert np.abs(np.array(gate["triangles"]) - corners).max() <= 0.5e-4 + 1e-9
    p = unpack(header, blob)["device_p"]
    assert p.shape == (1, len(poses["t_s"]))
    assert np.abs(p[0] - poses["device_position"][:, 0]).max() <= 0.5e-4 + 1e-7
    assert p[0, 0] == 0.0 and p[0, -1] == 1.0


def test_a_record_without_device_positions_draws_them_at_home_and_a_line_without_devices_has_none(gate_run, poses):
    data = read_dataset(gate_run / "run")
    header, blob = build_scene(data.line, data.name, data.runs[0], without_devices(poses))
    assert len(header["devices"]) == 1 and not unpack(header, blob)["device_p"].any()
    bare = data.line.model_copy(update={"devices": []})
    header, blob = build_scene(bare, data.name, data.runs[0], without_devices(poses))
    assert header["devices"] == [] and header["guide_openings"] == [] and "device_p" not in unpack(header, blob)
    # a pusher's opening (its paddle 1.0 .. 1.8 m and 0.15 m beyond each end) and its chute's plates, 0.5 m out
    pusher = Device.model_validate({"id": "p", "kind": "pusher", "x_m": 1.0, "length_m": 0.8, "side": "left"})
    header, _ = build_scene(bare.model_copy(update={"devices": [pusher]}), data.name, data.runs[0],
                            without_devices(poses))
    assert header["guide_openings"] == [[1, 0.85, 1.95]] and header["chutes"] == [[1, 0.85, 1.95, 0.5]]


@pytest.mark.parametrize("change, expected", [
    (lambda p: p.pop("device_id"), "array device_position without device_id"),
    (lambda p: p.update(device_position=p["device_position"][:-1]), "array device_position has shape"),
    (lambda p: p.update(device_position=np.full_like(p["device_position"], np.nan)), "not a finite number"),
])
def test_bad_device_positions_are_bad_input_naming_the_file(poses, tmp_path, change, expected):
    bad = dict(poses)
    change(bad)
    np.savez(tmp_path / "poses.npz", **bad)
    with pytest.raises(InputError, match=expected) as info:
        read_poses(tmp_path / "poses.npz")
    assert str(tmp_path / "poses.npz") in str(info.value)


# ------------------------------------------------------------------------------- in a browser
def image(png: bytes) -> np.ndarray:
    from PIL import Image
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def yellow(rgb: np.ndarray) -> bool:
    """The devices' safety yellow (also seen through a guide wall), not the belts, legs, floor or sky."""
    r, g, b = (int(v) for v in rgb)
    return r > b + 50 and g > b + 30


@needs_chromium
def test_the_gate_is_drawn_where_its_recorded_position_puts_it(gate_run, poses):
    line = read_dataset(gate_run / "run").line
    [shape] = device_shapes(line)
    p = poses["device_position"][:, 0]
    closed, opened = int(np.flatnonzero(p == 0.0)[-1]), int(np.flatnonzero(p == 1.0)[0])
    assert poses["t_s"][closed] < OPEN_AT_S + 0.02 < poses["t_s"][opened]
    far = shape.points_m[:, 0] == shape.points_m[:, 0].max()        # the flap's far edge
    top = far & (shape.points_m[:, 2] == shape.points_m[:, 2].max())
    flap_mid = np.array([0.3, 0.0, -0.005])                          # on the flap, 0.3 m from its hinge, mid-lane
    browser = Browser(1000, 600)
    try:
        browser.open((gate_run / "replay.html").as_uri())
        browser.eval("window.replay.ready")
        browser.eval("window.replay.setView('side'); window.replay.setCamera({dist: 1.5, target: [1.7, 0, -0.1]})")
        drawn, screen, shots = {}, {}, {}
        for name, k in (("closed", closed), ("opened", opened)):
            browser.eval(f"window.replay.setTime({float(poses['t_s'][k])!r})")
            drawn[name] = browser.eval("window.replay.devicePose(0)")
            assert browser.eval("window.replay.devicePositions()")[0]["p"] == pytest.approx(p[k], abs=1e-4)
            origin, rotvec = shape.pose(float(p[k]))
            world = Rotation.from_rotvec(rotvec).apply(flap_mid) + origin
            screen[name] = browser.eval(f"window.replay.project({world.tolist()})")[:2]
            shots[name] = image(browser.screenshot())
    finally:
        browser.close()

    # what the page drew with: the plant's pose of each corner at the recorded p
    for name, k in (("closed", closed), ("opened", opened)):
        assert drawn[name] is not None and drawn[name]["p"] == pytest.approx(p[k], abs=1e-4)
        origin, rotvec = shape.pose(float(p[k]))
        expected = Rotation.from_rotvec(rotvec).apply(shape.points_m[shape.triangles].reshape(-1, 3)) + origin
        assert np.abs(np.array(drawn[name]["corners"]) - expected).max() < 2e-4
    corners = {name: np.array(d["corners"]) for name, d in drawn.items()}
    local = shape.points_m[shape.triangles].reshape(-1, 3)
    is_far_top = (local[:, None] == shape.points_m[top][None]).all(axis=-1).any(axis=1)
    drop = corners["closed"][is_far_top, 2].mean() - corners["opened"][is_far_top, 2].mean()
    assert drop == pytest.approx(FLAP_M * np.sin(shape.travel), abs=0.001)   # 60 deg: 0.303 m lower

    # the pixels: the flap is where the page says, closed bridging the gap, open hanging into it
    at = {name: (int(round(y)), int(round(x))) for name, (x, y) in screen.items()}
    assert yellow(shots["closed"][at["closed"]]) and not yellow(shots["opened"][at["closed"]]), shots["closed"][at["closed"]]
    assert yellow(shots["opened"][at["opened"]]) and not yellow(shots["closed"][at["opened"]]), shots["opened"][at["opened"]]


@needs_chromium
def test_a_page_from_a_record_without_device_positions_draws_the_gate_at_home(gate_run, poses, tmp_path):
    run = tmp_path / "old"
    run.mkdir()
    (run / "run").symlink_to(gate_run / "run")
    np.savez_compressed(run / "poses.npz", **without_devices(poses))
    page = write_replay(run)
    browser = Browser(1000, 600)
    try:
        browser.open(page.as_uri())
        browser.eval("window.replay.ready")
        assert browser.eval("document.body.dataset.ready") == "1"
        browser.eval("window.replay.setTime(2.0)")
        pose = browser.eval("window.replay.devicePose(0)")
    finally:
        browser.close()
    assert pose["p"] == 0 and pose["matrix"][:11] == pytest.approx([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1])
