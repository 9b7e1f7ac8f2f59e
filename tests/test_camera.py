"""The vision sensor (``[[line.cameras]]``, ``plant.sim.camera``): its signals against hand-placed fish.

Fish are dropped flat from 1 cm onto a stopped belt at known places and headings and left to settle; a straight
fish of length L with its mid-length point at x and heading along +x has its snout at x + L/2 and its tail tip at
x - L/2, so the camera's numbers are known without the camera (within the outline's rounding, 2 cm).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from plant.contract.line import Line
from plant.errors import InputError
from plant.sim.plant import Plant
from plant.sim.ports import PlantPorts
from plant.validation import validate
from tests.plant_helpers import fish

from fishfmu import commands
from plant.contract.measured import read_dataset

LENGTH_M = 0.6


def camera_line(**camera) -> Line:
    return Line.model_validate({
        "guide_width_m": 0.5,
        "conveyors": [{"id": "c1", "x_start_m": 0.0, "length_m": 3.0, "width_m": 0.5, "z_top_m": 0.0}],
        "cameras": [{"id": "cam", "x_start_m": 0.5, "x_end_m": 2.5, "rate_hz": 50.0, "latency_s": 0.04,
                     "position_noise_m": 0.0, **camera}]})


def settle(line: Line, fishes: list, t_s: float = 0.6, seed: int = 0) -> tuple[Plant, list]:
    plant = Plant(line, fishes, seed=seed)
    outputs = [plant.step({"c1": 0.0}) for _ in range(round(t_s / 0.01))]
    return plant, outputs


def test_two_fish_apart_are_counted_and_the_leading_one_measured():
    plant, out = settle(camera_line(), [fish("f1", LENGTH_M, x_m=2.0, yaw_rad=0.0),
                                         fish("f2", LENGTH_M, x_m=1.2, yaw_rad=math.pi)])
    last = out[-1].port_values()
    assert last["cam.count"] == 2 and last["cam.events"] == 2
    assert last["cam.double"] is False  # 0.2 m apart along x (f1 from 1.7, f2 up to 1.5)
    assert last["cam.lead_x"] == pytest.approx(2.0 + LENGTH_M / 2, abs=0.02)
    assert last["cam.lead_length"] == pytest.approx(LENGTH_M, abs=0.02)
    assert last["cam.lead_heading"] == 1
    assert isinstance(last["cam.count"], int) and isinstance(last["cam.lead_heading"], int)


def test_fish_side_by_side_are_a_double_and_a_tail_first_leader_says_so():
    _, out = settle(camera_line(), [fish("f1", LENGTH_M, x_m=2.0, y_m=-0.1, yaw_rad=math.pi),
                                    fish("f2", LENGTH_M, x_m=1.8, y_m=0.13, yaw_rad=0.0)])
    last = out[-1].port_values()
    assert last["cam.count"] == 2 and last["cam.double"] is True
    assert last["cam.lead_heading"] == -1  # f1 leads (front at 2.3 m) and lies snout upstream


def test_a_gap_below_double_gap_is_a_double_and_above_it_is_not():
    # f1 from 1.70 m, f2 up to 1.66 m: 4 cm apart
    fishes = [fish("f1", LENGTH_M, x_m=2.0), fish("f2", LENGTH_M, x_m=1.36)]
    _, out = settle(camera_line(double_gap_m=0.08), fishes)
    assert out[-1].port_values()["cam.double"] is True and out[-1].port_values()["cam.lead_double"] is True
    _, out = settle(camera_line(double_gap_m=0.01), fishes)
    assert out[-1].port_values()["cam.double"] is False and out[-1].port_values()["cam.lead_double"] is False


def test_a_single_leader_ahead_of_a_double_is_not_a_lead_double():
    # f1 alone ahead (1.85 to 2.45 m), f2 (1.15 to 1.75 m) 0.1 m behind it, f3 up to 1.11 m: 4 cm behind f2
    _, out = settle(camera_line(double_gap_m=0.08), [fish("f1", LENGTH_M, x_m=2.15), fish("f2", LENGTH_M, x_m=1.45),
                                                     fish("f3", LENGTH_M, x_m=0.81)])
    last = out[-1].port_values()
    assert last["cam.count"] == 3 and last["cam.double"] is True and last["cam.lead_double"] is False


def test_a_fish_seen_in_a_double_stays_one_when_its_partner_has_left_the_view():
    # f1 (1.70 to 2.30 m) and f2 (up to 1.66 m) 4 cm apart, both in view; the belt then carries them 0.88 m on:
    # f1 wholly past the view's end (2.5 m), f2 leading alone (its front just past the end: seen up to it)
    plant = Plant(camera_line(double_gap_m=0.08), [fish("f1", LENGTH_M, x_m=2.0), fish("f2", LENGTH_M, x_m=1.36)])
    out = [plant.step({"c1": 0.0}).port_values() for _ in range(60)]
    assert out[-1]["cam.lead_double"] is True and out[-1]["cam.lead_x"] == pytest.approx(2.3, abs=0.02)
    out = [plant.step({"c1": 0.41}).port_values() for _ in range(215)]
    lead = out[-1]
    assert lead["cam.count"] == 1 and lead["cam.double"] is False
    assert lead["cam.lead_x"] == pytest.approx(2.5, abs=0.001) and lead["cam.lead_double"] is True


def test_a_fish_partly_in_view_is_as_long_as_the_part_in_view():
    _, out = settle(camera_line(x_end_m=2.1), [fish("f1", LENGTH_M, x_m=2.0)])  # snout at 2.3, view ends at 2.1
    last = out[-1].port_values()
    assert last["cam.lead_x"] == pytest.approx(2.1, abs=1e-9)
    assert last["cam.lead_length"] == pytest.approx(2.1 - (2.0 - LENGTH_M / 2), abs=0.02)


def test_frames_come_at_the_rate_and_their_results_after_the_latency():
    # frames at 0, 0.04, 0.08, ... (25 Hz); the fish is on the line from the step at 0.05 s; the first frame
    # with it is the one at 0.08 s, on the outputs from 0.08 + 0.1 s
    _, out = settle(camera_line(rate_hz=25.0, latency_s=0.1), [fish("f1", LENGTH_M, x_m=1.5, t_s=0.05)], t_s=0.4)
    first = next(o.t_s for o in out if o.port_values()["cam.count"] == 1)
    assert first == pytest.approx(0.18, abs=1e-9)
    assert all(o.port_values()["cam.count"] == 0 and o.port_values()["cam.lead_heading"] == 0 for o in out
               if o.t_s < first)
    # the results counter steps with each result: frame k (due at 0.04 k s, taken at the first step then: 0.01 s for
    # the first) is result k + 1, out 0.1 s after it was taken
    results = {round(o.t_s, 6): o.port_values()["cam.results"] for o in out}
    assert (results[0.1], results[0.11], results[0.13], results[0.14], results[0.4]) == (0, 1, 1, 2, 8)


def test_positions_carry_the_set_noise_and_no_bias():
    truth = settle(camera_line(), [fish("f1", LENGTH_M, x_m=1.5)], t_s=0.6)[1][-1].port_values()["cam.lead_x"]
    plant, _ = settle(camera_line(position_noise_m=0.01), [fish("f1", LENGTH_M, x_m=1.5)], t_s=0.6, seed=3)
    seen = []
    for _ in range(400):  # 4 s at 50 frames a second: 200 frames, the fish at rest
        out = plant.step({"c1": 0.0})
        seen.append(out.port_values()["cam.lead_x"])
    frames = np.array(seen[::2])  # one value per frame (a frame every second step)
    assert np.std(frames) == pytest.approx(0.01, rel=0.2)
    assert np.mean(frames) == pytest.approx(truth, abs=0.003)
    again, _ = settle(camera_line(position_noise_m=0.01), [fish("f1", LENGTH_M, x_m=1.5)], t_s=0.6, seed=3)
    assert [again.step({"c1": 0.0}).port_values()["cam.lead_x"] for _ in range(10)] == seen[:10]  # seeded


def test_detections_name_fish_by_track_and_each_frame_once():
    plant = Plant(camera_line(), [fish("f1", LENGTH_M, x_m=2.0), fish("f2", LENGTH_M, x_m=1.2, yaw_rad=math.pi)])
    rows = []
    for _ in range(60):
        plant.step({"c1": 0.0})
        rows += plant.state.detections
    assert {r[2] for r in rows} == {1, 2}  # tracks, not the plant's fish ids
    times = sorted({r[0] for r in rows})
    assert np.allclose(np.diff(times), 0.02)  # 50 frames a second
    assert all(sum(1 for r in rows if r[0] == t) == 2 for t in times)


def test_the_cameras_ports_follow_the_photo_eyes():
    ports = PlantPorts.of(camera_line())
    assert ports.outputs()[-8:] == ["cam.count", "cam.double", "cam.lead_double", "cam.lead_x", "cam.lead_length",
                                    "cam.lead_heading",
                                    "cam.events", "cam.results"]


@pytest.mark.parametrize("camera, key", [({"x_start_m": 2.0, "x_end_m": 1.0}, "line.cameras[0].x_end_m"),
                                         ({"x_end_m": 3.5}, "line.cameras[0].x_end_m"),
                                         ({"id": "c1"}, "line.conveyors"),
                                         ({"rate_hz": 0.0}, "line.cameras[0].rate_hz")])
def test_a_camera_off_the_line_or_named_twice_is_refused_naming_its_key(camera, key):
    data = camera_line().model_dump()
    data["cameras"][0].update(camera)
    with pytest.raises(InputError) as err:
        validate(Line, data, prefix="line")
    assert key in str(err.value)


def test_a_run_with_a_camera_logs_each_fish_once_as_a_track_and_reads_back(tmp_path):
    """The paper's dumped line with a camera over its last belt: every fish that reaches the outfeed passes the
    camera, so it is one track, first seen when its front crosses into the field; the run's detections.csv reads
    back through the measured-data reader."""
    paper = Path(__file__).parents[1] / "scenarios" / "paper_dump.toml"
    text = paper.read_text()
    at = text.index("[[line.photoeyes]]")
    scenario = tmp_path / "camera.toml"
    scenario.write_text(text[:at] + '[[line.cameras]]\nid = "cam"\nx_start_m = 5.2\nx_end_m = 6.1\n\n' + text[at:])
    done = commands.run(scenario, tmp_path / "out", {"fish.count": 6, "expect": {}}, report=False)
    assert done.result.status == "ok"
    run = read_dataset(tmp_path / "out" / "run", check_physics=False).runs[0]
    det = run.detections
    out = done.result.kpis["fish_in"] - done.result.kpis["lost"]
    assert set(det["camera_id"]) == {"cam"} and sorted(det["track"].unique()) == list(range(1, out + 1))
    first = det.groupby("track")["x_back_m"].first()
    assert (first < 5.2 + 0.05).all()  # a fish is first seen entering at the field's upstream edge
    assert det["length_m"].max() < 0.9 and set(det["heading"]) <= {1, -1}
