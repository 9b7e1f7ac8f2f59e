"""The 3D replay page: packing in Python, and the page itself in a real (headless) Chromium."""

from __future__ import annotations

import io
import re
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from typer.testing import CliRunner

from plant.contract.measured import read_dataset
from plant.sim.state import FishStatus

from fishfmu.cli import app
from fishfmu.output.run_folder import prepare_out_dir, write_outputs
from fishfmu.output.replay import (belt_travel, decode_ints, encode_ints, hold_hidden, read_header, unpack,
                            write_replay)
from fishfmu.cosim.runner import run_scenario
from fishfmu.scenario.schema import load_scenario

from tests.chromium import CHROMIUM, Browser

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
PILOT = Path(__file__).parents[2] / "shared" / "data" / "pilot_a"
SHORT = {"fish.count": 5, "run.duration_s": 9.0, "fish.first_drop_s": 3.0}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A short paper run (5 fish dropped at 3-4 s, 9 s) with poses, and its replay page."""
    result = run_scenario(load_scenario(PAPER, SHORT), PAPER, record_poses=True)
    assert result.status == "ok"
    out = prepare_out_dir(tmp_path_factory.mktemp("replay") / "run", overwrite=False)
    write_outputs(result, out, report=False)
    write_replay(out)
    return out


@pytest.fixture(scope="module")
def poses(run_dir) -> dict[str, np.ndarray]:
    with np.load(run_dir / "poses.npz") as npz:
        return {k: npz[k] for k in npz.files}


# ------------------------------------------------------------------------------- Python side
@settings(max_examples=60, deadline=None)
@given(hnp.arrays(np.int64, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=30),
                  elements=st.integers(-2**31, 2**31 - 1)))
def test_int_codec_round_trips_any_int32_rows(values):
    assert np.array_equal(decode_ints(encode_ints(values), *values.shape), values)


def test_page_is_one_file_that_needs_nothing_from_the_network(run_dir):
    html = (run_dir / "replay.html").read_text()
    assert not re.search(r"https?://", html)
    assert not re.search(r"<(script|img|iframe)[^>]*\bsrc=|<link\b|@import|url\(", html)
    assert "fetch(" not in html and "XMLHttpRequest" not in html
    # 9 s of 5 fish: the page is mostly its own code (~40 kB) and the data ~ (fish x seconds)
    assert (run_dir / "replay.html").stat().st_size < 150_000


def test_packed_poses_decode_to_the_recorded_ones(run_dir, poses):
    header, blob = read_header(run_dir / "replay.html")
    a = unpack(header, blob)
    F, B = poses["pos"].shape[:2]
    assert np.allclose(a["t"][0], poses["t_s"], atol=0.0005)
    pos = a["pos"].reshape(B, 3, F).transpose(2, 0, 1)
    quat = a["quat"].reshape(B, 4, F).transpose(2, 0, 1)
    visible = poses["status"][:, poses["body_fish"]] == FishStatus.ON_LINE
    assert visible.sum() > 0.5 * visible.size
    assert np.abs(pos - poses["pos"])[visible].max() <= 0.0005 + 1e-6          # mm quantum, rounded
    same_sign = np.abs(quat - poses["quat"]).max(axis=-1)
    other_sign = np.abs(quat + poses["quat"]).max(axis=-1)                     # q and -q: one rotation
    assert np.minimum(same_sign, other_sign)[visible].max() <= 0.5 / 4096 + 1e-6
    assert np.array_equal(a["status"].T, poses["status"])
    assert header["fish"]["ids"] == [str(f) for f in poses["fish_id"]]


def test_hidden_fish_hold_their_nearest_visible_pose():
    values = np.arange(6.0)[:, None] * [1.0, 10.0]
    visible = np.array([False, False, True, True, False, True])
    held = hold_hidden(values, visible)
    assert held[:, 0].tolist() == [2, 2, 2, 3, 3, 5]


def test_belt_travel_is_the_integral_of_the_belt_speed():
    # 0.5 m/s from 0 to 2 s, then a ramp to 1.5 m/s at 3 s: 1.0 m by 2 s, + (0.5 + 1.5) / 2 = 2.0 m by 3 s
    t = np.round(np.arange(0.01, 3.001, 0.01), 2)
    v = np.where(t <= 2.0, 0.5, 0.5 + (t - 2.0))
    belts = pd.DataFrame({"t_s": t, "conveyor_id": "c1", "setpoint_mps": v, "speed_mps": v})
    travel, speed = belt_travel(belts, ["c1"], np.array([1.0, 2.0, 3.0]))
    assert travel[0] == pytest.approx([0.5, 1.0, 2.0], abs=1e-6)
    assert speed[0] == pytest.approx([0.5, 0.5, 1.5])


def test_measured_tracks_are_packed_per_fish(run_dir, tmp_path):
    run = read_dataset(PILOT).runs[0]
    page = write_replay(run_dir, tmp_path / "compare.html", measured=(run.fish, run.tracks))
    header, blob = read_header(page)
    a = unpack(header, blob)
    for f in header["measured"]["fish"]:
        tr = run.tracks[run.tracks["fish_id"] == f["id"]].sort_values("t_s")
        sl = slice(f["start"], f["start"] + f["count"])
        assert np.allclose(a["m_t"][0, sl], tr["t_s"], atol=0.0005)
        assert np.allclose(a["m_xy"][0, sl], tr["x_m"], atol=0.0005)
        assert np.allclose(np.cos(a["m_yaw"][0, sl]), np.cos(tr["yaw_rad"]), atol=1e-3)
        fish = run.fish.set_index("fish_id").loc[f["id"]]
        assert f["length_m"] == pytest.approx(fish["length_m"], abs=1e-4)
        assert f["height_m"] == pytest.approx(fish["height_m"], abs=1e-4)
    assert header["duration_s"] >= run.tracks["t_s"].max()


def test_replay_command_writes_the_page_and_names_a_folder_without_poses(run_dir, tmp_path):
    runner = CliRunner()
    r = runner.invoke(app, ["replay", str(run_dir), "--out", str(tmp_path / "r.html")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "r.html").read_text().startswith("<!DOCTYPE html>")
    (tmp_path / "empty").mkdir()
    r = runner.invoke(app, ["replay", str(tmp_path / "empty")])
    assert r.exit_code != 0 and "poses.npz" in str(r.exception)


# ------------------------------------------------------------------------------- in a browser
needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(), reason=f"no {CHROMIUM}: `apt-get install chromium` "
                                    "(.ci/run does) to test the page in a real browser")


@pytest.fixture(scope="module")
def browser():
    with Browser(1000, 600) as b:
        yield b


@pytest.fixture()
def page(browser, run_dir):
    browser.open((run_dir / "replay.html").as_uri())
    browser.eval("window.replay.ready")
    return browser


def image(png: bytes) -> np.ndarray:
    from PIL import Image
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def projected(points: np.ndarray, view_projection: list[float], size: list[float]) -> np.ndarray:
    """World points (n, 3) -> CSS pixels, with the page's camera matrix (column-major, as WebGL)."""
    m = np.array(view_projection).reshape(4, 4).T
    clip = np.c_[points, np.ones(len(points))] @ m.T
    ndc = clip[:, :3] / clip[:, 3:]
    return np.c_[(ndc[:, 0] * 0.5 + 0.5) * size[0], (0.5 - ndc[:, 1] * 0.5) * size[1]]


@needs_chromium
def test_page_renders_from_a_file_in_headless_chromium(page):
    assert page.eval("document.body.dataset.ready") == "1"
    page.eval("window.replay.setTime(6.0)")
    img = image(page.screenshot())
    assert img.shape[:2] == (600, 1000)
    view = img[80:540]                                     # the 3D view between the text and the controls
    assert view.std() > 20
    assert len(np.unique(view.reshape(-1, 3) // 16, axis=0)) > 50


@needs_chromium
def test_fish_are_drawn_where_the_recorded_poses_put_them(page, poses):
    # the last frame with every fish on the line
    k = int(np.flatnonzero((poses["status"] == FishStatus.ON_LINE).all(axis=1))[-1])
    page.eval(f"window.replay.setView('top'); window.replay.setTime({float(poses['t_s'][k])!r})")
    vp, size = page.eval("window.replay.viewProjection()"), page.eval("window.replay.canvasSize()")
    expected = projected(poses["pos"][k].astype(float), vp, size)
    drawn = page.eval("window.replay.fishScreenPositions()")
    assert all(f["visible"] for f in drawn)
    got = np.array([b[:2] for f in drawn for b in f["bodies"]])
    assert np.abs(got - expected).max() < 1.0                         # 1 mm quantum is < 0.2 px here

    # the pixels: with and without the fish, they differ where the bodies are and nowhere far from them
    with_fish = image(page.screenshot())
    page.eval("window.replay.setLayer('sim', false)")
    without = image(page.screenshot())
    page.eval("window.replay.setLayer('sim', true)")
    changed = np.abs(with_fish - without).sum(axis=-1) > 30
    at_bodies = [changed[int(round(y)), int(round(x))] for x, y in expected]
    assert np.mean(at_bodies) >= 0.9
    ys, xs = np.nonzero(changed)
    px_per_m = np.linalg.norm(np.diff(projected(np.array([[3.0, 0, 0], [4.0, 0, 0]]), vp, size), axis=0))
    far = np.min(np.hypot(xs[:, None] - expected[:, 0], ys[:, None] - expected[:, 1]), axis=1) > 0.25 * px_per_m
    # nothing drawn more than 25 cm from a body centre (the longest body, the joined fish's tail with its fin, is
    # under 32 cm with its centre of mass towards its thick end; the others under 17 cm)
    assert far.mean() < 0.01

    # between two frames the page interpolates
    t_mid = float(0.5 * (poses["t_s"][k - 1] + poses["t_s"][k]))
    page.eval(f"window.replay.setTime({t_mid!r})")
    world = np.array(page.eval("window.replay.bodyWorldPositions()"))
    assert np.abs(world[:, :3] - 0.5 * (poses["pos"][k - 1] + poses["pos"][k])).max() < 0.0015


@needs_chromium
def test_photoeye_lights_up_while_blocked_and_belt_stripes_follow_the_belt(page, run_dir):
    header, _ = read_header(run_dir / "replay.html")
    pe_id, (t_on, t_off) = next((p, iv[0]) for p, iv in header["photoeyes"].items() if iv and iv[0][1] - iv[0][0] > 0.1)
    pe = next(p for p in header["line"]["photoeyes"] if p["id"] == pe_id)
    head = [pe["x_m"], -(header["line"]["guide_width_m"] / 2 + 0.06 + 0.015), pe["z_m"] + 0.04]  # the near sensor head
    colour = {}
    for name, t in (("blocked", 0.5 * (t_on + t_off)), ("clear", t_on - 0.05)):
        page.eval(f"window.replay.setTime({t!r})")
        assert page.eval("window.replay.photoeyesBlocked()")[pe_id] == (name == "blocked")
        x, y = page.eval(f"window.replay.project({head})")[:2]
        colour[name] = image(page.screenshot())[int(round(y)), int(round(x))]
    assert colour["blocked"][0] > 150 and colour["blocked"][1] < 80, colour      # red
    assert colour["clear"][1] > colour["clear"][0] + 40, colour                    # green

    belts = read_dataset(run_dir / "run").runs[0].belts
    log = belts[belts["conveyor_id"] == "c4"]
    page.eval("window.replay.setTime(8.0)")
    travel = page.eval("window.replay.beltTravel()")[3]
    t, v = log["t_s"].to_numpy(), log["speed_mps"].to_numpy()
    upto = t <= 8.0 + 1e-9
    t, v = t[upto], v[upto]
    assert travel == pytest.approx(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t)) + v[0] * t[0], abs=0.002)


@needs_chromium
def test_controls_play_pause_speed_slider_and_camera(page):
    page.eval("window.replay.setTime(1.0)")
    page.click(*page.centre_of("#play"))
    assert page.eval("window.replay.playing()")
    t0, w0 = page.eval("window.replay.time()"), time.monotonic()
    time.sleep(0.5)
    t1, w1 = page.eval("window.replay.time()"), time.monotonic()
    assert 0.5 * (w1 - w0) < t1 - t0 < 1.5 * (w1 - w0) + 0.1            # real time at 1x
    page.click(*page.centre_of("#play"))
    assert not page.eval("window.replay.playing()")
    t2 = page.eval("window.replay.time()")
    time.sleep(0.3)
    assert page.eval("window.replay.time()") == t2

    page.eval("const s = document.getElementById('speed'); s.value = '4'; s.dispatchEvent(new Event('change'))")
    assert page.eval("window.replay.speed()") == 4
    page.eval("window.replay.play()")
    t0, w0 = page.eval("window.replay.time()"), time.monotonic()
    time.sleep(0.4)
    t1, w1 = page.eval("window.replay.time()"), time.monotonic()
    page.eval("window.replay.pause()")
    assert t1 - t0 > 2.0 * (w1 - w0)

    left, top, width, height = page.eval(
        "(() => { const r = document.getElementById('time').getBoundingClientRect(); "
        "return [r.left, r.top, r.width, r.height]; })()")
    page.click(left + 0.25 * width, top + height / 2)
    duration = page.eval("window.replay.duration()")
    assert page.eval("window.replay.time()") == pytest.approx(0.25 * duration, abs=0.06 * duration)
    assert "s /" in page.eval("document.getElementById('clock').textContent")

    before = page.eval("window.replay.camera()")
    page.mouse_drag([(500, 300), (540, 310), (600, 320)])
    after = page.eval("window.replay.camera()")
    assert after["yaw"] != pytest.approx(before["yaw"]) and after["pitch"] != pytest.approx(before["pitch"])
    page.call("Input.dispatchMouseEvent", type="mouseWheel", x=500, y=300, deltaX=0, deltaY=300)
    assert page.eval("window.replay.camera().dist") > after["dist"]


@needs_chromium
def test_measured_fish_are_overlaid_at_their_tracked_positions_and_hidden_in_gaps(browser, run_dir, tmp_path):
    fish = pd.DataFrame({"fish_id": ["f01"], "length_m": [0.6], "height_m": [0.14]})
    t = np.r_[np.arange(4.0, 6.0, 0.04), np.arange(7.0, 8.0, 0.04)]            # tracking lost 6-7 s
    tracks = pd.DataFrame({"t_s": t, "fish_id": "f01", "x_m": 1.0 + 0.25 * (t - 4.0), "y_m": 0.05,
                           "yaw_rad": 0.3})
    page = write_replay(run_dir, tmp_path / "compare.html", measured=(fish, tracks))
    browser.open(page.as_uri())
    browser.eval("window.replay.ready")
    browser.eval("window.replay.setView('top'); window.replay.setLayer('sim', false); window.replay.setTime(5.02)")
    [m] = browser.eval("window.replay.measuredFish()")
    assert (m["x"], m["y"], m["yaw"]) == pytest.approx((1.0 + 0.25 * 1.02, 0.05, 0.3), abs=0.001)
    with_outline = image(browser.screenshot())
    x, y = browser.eval(f"window.replay.project([{m['x']}, {m['y']}, 0.004])")[:2]
    browser.eval("window.replay.setLayer('measured', false)")
    without = image(browser.screenshot())
    assert np.abs(with_outline[int(y), int(x)] - without[int(y), int(x)]).sum() > 30
    browser.eval("window.replay.setTime(6.5)")
    assert browser.eval("window.replay.measuredFish()") == []
