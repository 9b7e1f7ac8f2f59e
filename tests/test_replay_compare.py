"""The replay of a comparison: ``fishfmu compare`` writes a 3D page per run with the measured fish
drawn as ghosts over the re-simulated ones (issue 9), checked in Python and in headless Chromium.

The dataset is tiny and made here: two fish simulated on two belts, written as a measured dataset
with their tracks moved 0.4 m downstream (so that a ghost drawn at the simulated place instead of
the measured one shows), a tracking gap, and a measured photo-eye interval that the simulation has
not, so the measured and simulated beams differ.
"""

from __future__ import annotations

import io
import pickle
import re
from pathlib import Path

import numpy as np
import pytest

from plant.contract.line import KpiSettings
from plant.contract.measured import Dataset, Run, read_dataset, write_dataset
from plant.sim.simulate import simulate_plant

from fishfmu.analysis.compare import compare_dataset, write_comparison
from fishfmu.output.replay import read_header, unpack
from fishfmu.analysis.resim import resimulate

from tests.chromium import CHROMIUM, Browser
from tests.plant_helpers import fish, straight_line

SHIFT_M = 0.4                  # measured tracks lie this far downstream of where the fish were simulated
GAP = ("f02", 2.0, 2.8)        # f02's tracking is lost here (longer than the page's 0.5 s)
EXTRA_BLOCK = ("pe_b", 0.4, 0.9)   # a measured beam interruption the simulation has not (no fish there yet)


@pytest.fixture(scope="module")
def measured(tmp_path_factory) -> Path:
    line = straight_line(("c1", 0.0, 1.5, 0.0), ("c2", 1.51, 1.5, -0.02),
                         photoeyes=(("pe_a", 1.4, 0.015), ("pe_b", 2.9, -0.005)))
    fishes = [fish("f01", 0.6, x_m=0.4, y_m=0.05, t_s=0.3), fish("f02", 0.5, x_m=0.4, y_m=-0.08, t_s=1.3, yaw_rad=0.2)]
    sim = simulate_plant(line, fishes, {"c1": 0.6, "c2": 1.0}, 8.0)
    tracks = sim.tracks.assign(x_m=sim.tracks["x_m"] + SHIFT_M)
    fid, t0, t1 = GAP
    tracks = tracks[~((tracks["fish_id"] == fid) & tracks["t_s"].between(t0, t1))].reset_index(drop=True)
    pe = sim.photoeyes.copy()
    pe.loc[len(pe)] = list(EXTRA_BLOCK)
    fish_table = sim.fish.copy()
    fish_table.loc[fish_table["fish_id"] == "f02", "height_m"] = np.nan    # filled by the reader's regression
    root = tmp_path_factory.mktemp("replay_compare") / "tiny"
    write_dataset(Dataset("tiny", "two fish, shifted tracks", line, KpiSettings(outfeed_photoeye="pe_b"),
                          [Run("r1", 24.0, "shifted", fish_table, tracks, pe.sort_values("t_on_s"), sim.belts)]), root)
    return root


@pytest.fixture(scope="module")
def compared(measured, tmp_path_factory):
    dataset = read_dataset(measured)
    c = compare_dataset(dataset, workers=1)
    out = tmp_path_factory.mktemp("compare_out")
    paths = write_comparison(c, out)
    return dataset, c, out, paths


# ------------------------------------------------------------------------------- Python side
def test_resimulation_records_poses_only_when_asked(measured, compared):
    dataset, c, _, _ = compared
    [r] = c.resims
    poses = r.sim.poses
    assert poses is not None and len(poses["t_s"]) > 50
    assert np.allclose(np.diff(poses["t_s"]), 0.04, atol=1e-6)                     # 25 Hz
    assert poses["pos"].shape == (len(poses["t_s"]), 10, 3) and poses["status"].shape[1] == 2
    assert list(poses["fish_id"]) == ["f01", "f02"]
    back = pickle.loads(pickle.dumps(r))                  # what a spawn worker of resimulate_many sends back
    for k, v in poses.items():
        np.testing.assert_array_equal(back.sim.poses[k], v)
    plain = resimulate(dataset.line, dataset.runs[0], duration_s=1.0)
    assert plain.sim.poses is None                         # diagnose re-simulates many times: no poses by default


def test_compare_writes_a_replay_page_per_run_linked_from_the_report(compared):
    dataset, c, out, paths = compared
    page = out / "replay" / "r1.html"
    assert paths["replay"] == out / "replay" and page.is_file()
    report = paths["report"].read_text()
    assert 'href="replay/r1.html"' in report and "3D replays" in report
    html = page.read_text()
    assert not re.search(r"https?://", html) and not re.search(r"<(script|img|iframe)[^>]*\bsrc=|<link\b", html)
    assert page.stat().st_size < 120_000

    header, blob = read_header(page)
    a = unpack(header, blob)
    run = dataset.runs[0]
    assert header["run_id"] == "r1" and header["fish"]["ids"] == ["f01", "f02"]
    for f in header["measured"]["fish"]:
        tr = run.tracks[run.tracks["fish_id"] == f["id"]].sort_values("t_s")
        sl = slice(f["start"], f["start"] + f["count"])
        assert np.allclose(a["m_xy"][0, sl], tr["x_m"], atol=0.0005)
        size = run.fish.set_index("fish_id").loc[f["id"]]
        assert (f["length_m"], f["height_m"], f["width_m"]) == pytest.approx(
            (size["length_m"], size["height_m"], size["width_m"]), abs=1e-4)
    assert [0.4, 0.9] in header["measured"]["photoeyes"]["pe_b"]
    assert [0.4, 0.9] not in header["photoeyes"]["pe_b"]
    assert header["photoeyes"]["pe_a"] == [[round(x, 3), round(y, 3)] for x, y in
                                           c.resims[0].sim.photoeyes.query("sensor_id == 'pe_a'")[["t_on_s", "t_off_s"]].to_numpy()]


# ------------------------------------------------------------------------------- in a browser
needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(), reason=f"no {CHROMIUM}: `apt-get install chromium` "
                                    "(.ci/run does) to test the page in a real browser")


def image(png: bytes) -> np.ndarray:
    from PIL import Image
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


@pytest.fixture(scope="module")
def page(compared):
    _, _, out, _ = compared
    with Browser(1000, 600) as b:
        b.open((out / "replay" / "r1.html").as_uri())
        b.eval("window.replay.ready")
        yield b


@needs_chromium
def test_ghosts_are_drawn_where_the_measured_tracks_say_and_the_toggle_hides_them(page, compared):
    dataset, _, _, _ = compared
    tracks = dataset.runs[0].tracks
    assert page.eval("document.body.dataset.ready") == "1"
    assert page.eval("window.replay.showing()") == "both"
    t = 3.02                                                   # between two 25 Hz samples (3.00, 3.04)
    page.eval(f"window.replay.setView('top'); window.replay.setTime({t})")
    ghosts = {m["id"]: m for m in page.eval("window.replay.measuredFish()")}
    assert set(ghosts) == {"f01", "f02"}
    for fid, m in ghosts.items():
        tr = tracks[tracks["fish_id"] == fid]
        expected = [np.interp(t, tr["t_s"], tr[c]) for c in ("x_m", "y_m", "yaw_rad")]
        assert [m["x"], m["y"], m["yaw"]] == pytest.approx(expected, abs=0.0015)

    # pixels: the ghosts are what changes between "both" and "simulated", and they are at the tracks
    both = image(page.screenshot())
    page.click(*page.centre_of("#show-sim"))
    assert page.eval("window.replay.showing()") == "sim"
    assert page.eval("document.getElementById('show-sim').getAttribute('aria-pressed')") == "true"
    sim_only = image(page.screenshot())
    changed = np.abs(both - sim_only).sum(axis=-1) > 30
    changed[540:] = False                                      # the control bar (the pressed button)
    p0, p1 = (np.array(page.eval(f"window.replay.project([{x}, 0, 0])")[:2]) for x in (1.0, 2.0))
    px_per_m = np.linalg.norm(p1 - p0)
    line = read_header(compared[2] / "replay" / "r1.html")[0]["line"]
    for pe in line["photoeyes"]:                                # the lamps of the measured beams go too
        for side in (-1, 1):
            x, y = page.eval(f"window.replay.project([{pe['x_m']}, {side * (line['guide_width_m'] / 2 + 0.075)}, "
                             f"{pe['z_m'] + 0.09}])")[:2]
            r = int(0.05 * px_per_m)
            assert changed[int(y) - r:int(y) + r, int(x) - r:int(x) + r].any()
            changed[int(y) - r:int(y) + r, int(x) - r:int(x) + r] = False
    centres = np.array([page.eval(f"window.replay.project([{m['x']}, {m['y']}, 0.03])")[:2] for m in ghosts.values()])
    for x, y in centres:
        assert changed[int(round(y)) - 2:int(round(y)) + 3, int(round(x)) - 2:int(round(x)) + 3].mean() > 0.8
    ys, xs = np.nonzero(changed)
    dist = np.min(np.hypot(xs[:, None] - centres[:, 0], ys[:, None] - centres[:, 1]), axis=1) / px_per_m
    assert dist.max() < 0.36                                   # within half a fish length (0.3 m) and the edge
    # ... and not where the fish were simulated: SHIFT_M upstream, the simulated fish are drawn unchanged
    sim_bodies = [b for f in page.eval("window.replay.fishScreenPositions()") for b in f["bodies"]]
    far_from_ghosts = [b for b in sim_bodies if np.min(np.hypot(*(centres - b[:2]).T)) > 0.4 * px_per_m]
    assert far_from_ghosts
    assert not any(changed[int(round(y)), int(round(x))] for x, y, _ in far_from_ghosts)

    # "measured" hides the simulated fish and shows the ghosts again; "both" shows both
    page.click(*page.centre_of("#show-measured"))
    assert page.eval("window.replay.showing()") == "measured"
    assert not any(f["visible"] for f in page.eval("window.replay.fishScreenPositions()"))
    measured_only = image(page.screenshot())
    for x, y in centres:
        assert np.abs(measured_only[int(y), int(x)] - both[int(y), int(x)]).sum() < 40 < \
            np.abs(measured_only[int(y), int(x)] - sim_only[int(y), int(x)]).sum()
    page.eval("window.dispatchEvent(new KeyboardEvent('keydown', {key: 'm'}))")   # m: measured -> both
    assert page.eval("window.replay.showing()") == "both"


@needs_chromium
def test_ghosts_are_hidden_outside_their_tracks_and_in_gaps(page, compared):
    dataset, _, _, _ = compared
    tracks = dataset.runs[0].tracks
    fid, t0, t1 = GAP
    page.eval(f"window.replay.setTime({0.5 * (t0 + t1)})")
    assert fid not in {m["id"] for m in page.eval("window.replay.measuredFish()")}
    first = tracks.groupby("fish_id")["t_s"].min()
    last = tracks.groupby("fish_id")["t_s"].max()
    page.eval(f"window.replay.setTime({first['f02'] - 0.1})")
    assert "f02" not in {m["id"] for m in page.eval("window.replay.measuredFish()")}
    page.eval(f"window.replay.setTime({last['f01'] + 0.1})")
    assert "f01" not in {m["id"] for m in page.eval("window.replay.measuredFish()")}


@needs_chromium
def test_measured_photoeye_lamp_shows_the_measured_beam(page, compared):
    _, _, out, _ = compared
    pe_id, t_on, t_off = EXTRA_BLOCK
    line = read_header(out / "replay" / "r1.html")[0]["line"]
    pe = next(p for p in line["photoeyes"] if p["id"] == pe_id)
    reach = line["guide_width_m"] / 2 + 0.06
    lamp_top = [pe["x_m"], -(reach + 0.015), pe["z_m"] + 0.09]
    page.eval(f"window.replay.show('both'); window.replay.setView('top'); window.replay.setTime({0.5 * (t_on + t_off)})")
    assert page.eval("window.replay.measuredPhotoeyesBlocked()")[pe_id] is True
    assert page.eval("window.replay.photoeyesBlocked()")[pe_id] is False
    x, y = page.eval(f"window.replay.project({lamp_top})")[:2]
    r, g, b = image(page.screenshot())[int(round(y)), int(round(x))]
    assert r > 200 and 90 < g < 180 and b < 70, (r, g, b)                 # orange: measured blocked
    page.eval(f"window.replay.setTime({t_off + 0.05})")
    r, g, b = image(page.screenshot())[int(round(y)), int(round(x))]
    assert r > 190 and g > 190 and b > 170, (r, g, b)                     # pale: measured clear
