"""Actuated devices (``[[line.devices]]``): a reject gate drops a fish into its bin, a pusher moves one across at
its paddle's speed, a diverter steers one out of the lane; their actuators, ports, validation, KPIs and logs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from plant.contract.devices import GATE_DROP_M, device_shapes, step_for_devices
from plant.contract.kpis import compute_kpis
from plant.contract.line import KpiSettings, Line
from plant.contract.measured import PHOTOEYES, Run, empty_table, read_run, write_run
from plant.errors import InputError, SimulationError
from plant.sim.health import EnergyWatch
from plant.sim.plant import Plant
from plant.sim.ports import PlantPorts
from plant.sim.state import FishStatus
from plant.validation import validate
from tests.plant_helpers import fish

DT_S = 0.01


def two_belts(devices: list[dict], gap_m: float = 0.45) -> Line:
    return Line.model_validate({"guide_width_m": 0.5, "conveyors": [
        {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0},
        {"id": "c2", "x_start_m": 2.0 + gap_m, "length_m": 1.5, "width_m": 0.5, "z_top_m": -0.02}],
        "devices": devices})


GATE = {"id": "gate", "kind": "gate", "x_m": 2.0, "length_m": 0.43, "stroke_s": 0.2}


def run_plant(line: Line, fishes, speed_mps: float, command, t_end_s: float, watch: bool = True):
    """Step the plant to ``t_end_s`` with both belts at ``speed_mps`` and the devices' commands ``command(t)``;
    returns the plant and, per step, (t, mid-length points (n_fish, 3), device positions)."""
    plant = Plant(line, fishes)
    energy = EnergyWatch()
    log = []
    while plant.t_s < t_end_s - 1e-9:
        plant.step({"c1": speed_mps, "c2": speed_mps}, command(plant.t_s))
        if watch:
            energy.check(plant.state, DT_S)  # the devices' work is a source: no energy from nowhere
        poses = plant.state.fish_poses()
        log.append((plant.t_s, np.column_stack([poses.x_m, poses.y_m, poses.z_m]), plant.state.device_position.copy()))
    return plant, log


# ------------------------------------------------------------------------------------------- gate
@pytest.mark.parametrize("length_m", [0.42, 0.6, 0.75])
def test_an_open_gate_drops_the_fish_through_its_gap_and_a_closed_one_lets_it_pass(length_m):
    line = two_belts([GATE])
    shape = device_shapes(line)[0]
    opened, log = run_plant(line, [fish(x_m=1.0, length_m=length_m)], 1.25, lambda t: {"gate": True}, 3.0)
    assert opened.state.status[0] == FishStatus.REJECTED and opened.state.rejected_by[0] == 0
    last = [p[0] for _, p, _ in log if np.isfinite(p[0, 0])][-1]  # the last place it was seen: going down at the gate
    # seen last in the step before it was taken, falling: within 2 cm of the depth at which it is taken
    assert 2.0 - 0.1 <= last[0] <= 2.0 + 0.43 + 0.6 and last[2] < shape.hinge_z_m - GATE_DROP_M + 0.02
    assert opened.state.outputs.device_rejected == {"gate": 1}
    closed, log = run_plant(line, [fish(x_m=1.0, length_m=length_m)], 1.25, lambda t: {"gate": False}, 3.0)
    assert closed.state.status[0] == FishStatus.LEFT  # over the closed gate (a flap running at c1's speed) and c2
    crossing = [p[0] for _, p, _ in log if np.isfinite(p[0, 0]) and 2.0 <= p[0, 0] <= 2.45]
    assert crossing and min(z for _, _, z in crossing) > -0.03  # carried across at the belts' height, never down


def test_a_gate_hinged_just_after_its_belts_end_is_fed_by_that_belt_not_the_next():
    """The hinge 1 cm after c1's end (the schema allows it at or after the end): the flap runs at c1's speed and
    height, not at those of c2, which climbs at 20 deg from 2.45 m (its far end 1.5 tan 20 = 0.55 m up) at another
    speed.  It took c2 as its feeder: the flap hinged 0.5 m up, at c2's speed (the issue's run blew up)."""
    line = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
        {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0},
        {"id": "c2", "x_start_m": 2.45, "length_m": 1.5, "width_m": 0.5, "z_top_m": -0.02, "incline_deg": 20.0}],
        "devices": [GATE | {"x_m": 2.01}]})
    shape = device_shapes(line)[0]
    assert (shape.feeder, shape.hinge_z_m, shape.gap_from_m) == (0, pytest.approx(-0.005), 2.0)
    speeds = {"c1": 1.25, "c2": 0.4}

    def crossing(command):
        plant, energy, log = Plant(line, [fish(x_m=1.0)]), EnergyWatch(), []
        while plant.t_s < 2.5 - 1e-9:
            plant.step(speeds, {"gate": command})
            energy.check(plant.state, DT_S)
            poses = plant.state.fish_poses()
            log.append((plant.t_s, poses.x_m[0], poses.z_m[0]))
        return plant, np.array(log)

    closed, log = crossing(False)
    over = log[(log[:, 1] > 2.1) & (log[:, 1] < 2.3)]  # mid-point over the flap: most of the fish on it
    assert (over[-1, 1] - over[0, 1]) / (over[-1, 0] - over[0, 0]) == pytest.approx(1.25, abs=0.1)  # c1's, not 0.4
    assert over[:, 2].min() > -0.03 and closed.state.status[0] == FishStatus.ON_LINE  # across, on up c2
    assert log[-1, 1] > 2.5
    opened, _ = crossing(True)
    assert opened.state.status[0] == FishStatus.REJECTED and opened.state.outputs.device_rejected == {"gate": 1}


def test_the_gate_swings_down_at_its_stroke_rate_and_its_limit_switches_follow():
    line = two_belts([GATE])
    plant = Plant(line, [])
    seen = [plant.step({"c1": 0.0, "c2": 0.0}, {"gate": plant.t_s < 0.3}).port_values() for _ in range(60)]
    position = [s["gate.position"] for s in seen]
    assert position[:3] == pytest.approx([0.05, 0.10, 0.15])  # 0.2 s for the whole travel: 0.05 a step
    assert position[19] == 1.0 and seen[19]["gate.at_end"] and not seen[18]["gate.at_end"]
    assert not seen[0]["gate.at_home"] and seen[-1]["gate.at_home"] and seen[-1]["gate.position"] == 0.0
    # the flap's far edge goes down by its length x sin(60 deg) when open
    shape = device_shapes(line)[0]
    origin, rotvec = shape.pose(1.0)
    angle = np.linalg.norm(rotvec)
    assert origin[2] - shape.origin_m[2] == 0.0 and 0.43 * np.sin(angle) == pytest.approx(0.43 * np.sin(np.pi / 3))


# ----------------------------------------------------------------------------------------- pusher
def test_a_pusher_moves_a_fish_across_at_the_paddles_speed_and_out_of_the_lane():
    pusher = {"id": "p", "kind": "pusher", "x_m": 0.8, "length_m": 0.8, "stroke_s": 0.5, "side": "right"}
    line = two_belts([pusher], gap_m=0.01)
    plant, log = run_plant(line, [fish(x_m=1.2)], 0.0, lambda t: {"p": t >= 0.5}, 2.0)
    paddle_mps = 0.5 / 0.5  # the lane's width over the stroke time
    t = np.array([s for s, _, _ in log])
    y = np.array([p[0, 1] for _, p, _ in log])
    # once the paddle's face reaches the fish's near side (its face at y = 0.25 m at 0.5 s, the fish's side near
    # y = 0.05 m: from about 0.7 s) it carries the fish across at its own speed to the end of its stroke (1.0 s);
    # the fish's mid point lags a little as the soft body bends and rolls against the paddle
    pushing = (t >= 0.75) & (t <= 1.0) & np.isfinite(y)
    assert (y[pushing][-1] - y[pushing][0]) / (t[pushing][-1] - t[pushing][0]) == pytest.approx(-paddle_mps, rel=0.08)
    assert np.all(np.abs(y[(t < 0.6) & np.isfinite(y)]) < 0.005)  # before the paddle reaches it, where it was
    assert plant.state.status[0] == FishStatus.REJECTED and plant.state.outputs.device_rejected == {"p": 1}


# --------------------------------------------------------------------------------------- diverter
DIVERTER = {"id": "d", "kind": "diverter", "x_m": 1.0, "length_m": 0.8, "stroke_s": 0.3, "side": "right",
            "travel_deg": 45.0}


def test_a_swung_diverter_steers_a_fish_out_of_the_lane_and_one_at_home_is_a_guide():
    line = two_belts([DIVERTER], gap_m=0.01)
    swung, log = run_plant(line, [fish(x_m=0.5, y_m=0.1)], 0.4, lambda t: {"d": True}, 6.0)
    assert swung.state.status[0] == FishStatus.REJECTED
    seen = np.array([p[0] for _, p, _ in log if np.isfinite(p[0, 0])])
    assert seen[-1, 1] < -0.25  # out on the right, where the arm was the guide
    home, log = run_plant(line, [fish(x_m=0.5, y_m=-0.1)], 0.4, lambda t: {"d": False}, 10.0)
    assert home.state.status[0] == FishStatus.LEFT  # along the arm as along a guide, to the end of the line
    seen = np.array([p[0] for _, p, _ in log if np.isfinite(p[0, 0])])
    assert np.all(np.abs(seen[seen[:, 0] < 3.9, 1]) < 0.25)


# -------------------------------------------------------------------------------- ports, validation
def test_device_ports_are_a_command_in_and_position_switches_and_count_out():
    ports = PlantPorts.of(two_belts([GATE, DIVERTER]))
    assert ports.inputs() == ["c1.speed", "c2.speed", "gate.command", "d.command"]
    assert ports.outputs()[-8:] == ["gate.position", "gate.at_home", "gate.at_end", "gate.rejected",
                                    "d.position", "d.at_home", "d.at_end", "d.rejected"]


def test_a_command_for_a_device_the_line_lacks_is_refused():
    plant = Plant(two_belts([GATE]), [])
    with pytest.raises(KeyError, match="no device named gat"):
        plant.step({"c1": 0.0, "c2": 0.0}, {"gat": True})


@pytest.mark.parametrize("device, key, words", [
    ({"x_m": 1.5}, "devices[0].x_m", "must lie in the gap between two conveyors"),
    ({"length_m": 0.5}, "devices[0].x_m", "must lie in the gap"),
    ({"travel_m": 0.3}, "devices[0].travel_m", "a gate: it has no travel_m"),
    ({"kind": "pusher", "x_m": 3.6}, "devices[0].x_m", "must be over the line"),
    ({"id": "c1"}, "conveyors", "repeated: c1"),
])
def test_a_device_where_it_cannot_work_is_refused_naming_its_key(device, key, words):
    with pytest.raises(InputError, match=words) as err:
        validate(Line, two_belts([]).model_dump() | {"devices": [GATE | device]})
    assert err.value.where == key


# ------------------------------------------------------------------------------------- KPIs, logs
def test_rejected_and_good_rejected_by_hand(tmp_path):
    """f1 alone through the gate (singulated there, rejected: good), f2 and f3 touching (0.02 m apart) at the gate:
    f2 rejected (not good), f3 goes on alone to the outfeed beam (singulated there)."""
    line = Line.model_validate(two_belts([GATE]).model_dump() | {
        "photoeyes": [{"id": "pe_out", "x_m": 3.5, "z_m": -0.005}]})
    t = np.arange(0.0, 8.0, 0.04)

    def track(fish_id, x0, t_end):
        tt = t[t <= t_end + 1e-9]
        return pd.DataFrame({"t_s": tt, "fish_id": fish_id, "x_m": x0 + tt, "y_m": 0.0, "yaw_rad": 0.0})

    fishes = pd.DataFrame({"fish_id": ["f1", "f2", "f3"], "length_m": 0.6, "weight_kg": 2.0, "height_m": 0.15,
                           "width_m": 0.07, "hours_post_mortem": 6.0, "drop_t_s": 0.0, "drop_x_m": 0.5,
                           "drop_y_m": 0.0, "drop_yaw_rad": 0.0, "drop_z_m": 0.05})
    tracks = pd.concat([track("f1", 0.4, 1.8), track("f2", -1.0, 3.2), track("f3", -1.62, 8.0)], ignore_index=True)
    tb = np.arange(0.0, 8.0, 0.01)
    belts = pd.DataFrame({"t_s": np.repeat(tb, 2), "conveyor_id": np.tile(["c1", "c2"], len(tb)),
                          "setpoint_mps": 1.0, "speed_mps": 1.0})
    rejections = pd.DataFrame({"t_s": [1.9, 3.3], "device_id": ["gate", "gate"], "fish_id": ["f1", "f2"]})
    run = Run("r", 6.0, "", fishes, tracks, empty_table(PHOTOEYES), belts, rejections=rejections)
    k = compute_kpis(run, line, KpiSettings(outfeed_photoeye="pe_out", min_gap_m=0.05))
    assert (k["rejected"], k["good_rejected"], k["singulated"], k["doubles_out"], k["lost"]) == (2, 1, 1, 0, 0)
    assert k["rejected_by"] == {"gate": 2}
    # the devices' log in the measured-data format: written, read back, checked against the line
    write_run(run, tmp_path / "runs" / "r")
    back = read_run(tmp_path, {"id": "r"}, line, check_physics=False)
    assert back.rejections.to_dict("list") == rejections.to_dict("list")
    (tmp_path / "runs" / "r" / "rejections.csv").write_text("t_s,device_id,fish_id\n1.0,flap,f1\n")
    with pytest.raises(InputError, match="rejections.csv.*device_id 'flap': not a device of the line"):
        read_run(tmp_path, {"id": "r"}, line, check_physics=False)
    # a log that does not name its fish: rejected counted, good_rejected undefined
    unnamed = Run("r", 6.0, "", fishes, tracks, empty_table(PHOTOEYES), belts,
                  rejections=rejections.assign(fish_id=[None, None]))
    k = compute_kpis(unnamed, line, KpiSettings(outfeed_photoeye="pe_out", min_gap_m=0.05))
    assert k["rejected"] == 2 and k["good_rejected"] is None


# ----------------------------------------------------------------------------------- too fast for the step
def test_a_paddle_faster_than_the_step_allows_passes_through_the_fish_and_such_a_device_is_refused_naming_it():
    """The step is 1.25 ms and a fish's smallest contact sphere 12 mm: a paddle crossing the lane (0.5 m) in 0.105 s,
    4.76 m/s, moves 6 mm a step: the contact's explicit step gives the fish it hits energy from nowhere and the run
    failed as a 'numerical blow-up' blamed on the fish; in 0.21 s, 2.38 m/s (3 mm a step, a quarter of that sphere:
    the most a scenario may ask), it pushes the fish out.  check refuses the first naming the device's stroke_s and
    what to make it: 0.43 m x 60 deg in 0.02 s is 22.5 m/s, so at least 0.02 x 22.5 / 2.4 = 0.188 s."""
    from fishfmu.scenario.schema import load_scenario

    def push(stroke_s):
        pusher = {"id": "p", "kind": "pusher", "x_m": 0.8, "length_m": 0.8, "stroke_s": stroke_s, "side": "right"}
        return run_plant(two_belts([pusher], gap_m=0.01), [fish(x_m=1.2)], 0.0, lambda t: {"p": t >= 0.5}, 2.0)[0]

    with pytest.raises(SimulationError, match="numerical blow-up.*fish 'f01'"):
        push(0.105)
    assert push(0.21).state.status[0] == FishStatus.REJECTED
    with pytest.raises(InputError, match=r"gate 'gate' moves at 22\.5 m/s.*faster than 2\.4 m/s.*make stroke_s at "
                                         r"least 0\.188 s") as err:
        load_scenario("scenarios/reject_doubles.toml", {"line.devices[0].stroke_s": 0.02})
    assert err.value.where == "line.devices[0].stroke_s"
    assert load_scenario("scenarios/reject_doubles.toml", {"line.devices[0].stroke_s": 0.188}).line.devices[0].stroke_s


def test_the_default_step_is_shortened_for_a_fast_device_never_below_the_paper_fishs_and_a_given_one_is_kept():
    """A 0.43 m flap through 60 deg in 0.2 s: its tip at 0.43 x 1.047 / 0.2 = 2.25 m/s, more than the 1.5 m/s (a
    quarter of a 12 mm sphere per step) allowed at the joined fish's 2 ms, less than the 2.4 m/s at 1.25 ms."""
    from fishfmu.scenario.schema import load_scenario

    gate = two_belts([GATE])
    assert device_shapes(gate)[0].fastest_mps == pytest.approx(0.43 * np.radians(60.0) / 0.2)
    assert step_for_devices(gate, 0.01, 0.002) == 0.00125
    assert step_for_devices(two_belts([]), 0.01, 0.002) == 0.002      # no device: the fish's own step
    assert step_for_devices(gate, 0.01, 0.001) == 0.001                # already short enough: kept
    fast = two_belts([dict(GATE, stroke_s=0.02)])                      # 22.5 m/s: would need 0.13 ms
    assert step_for_devices(fast, 0.01, 0.002) == 0.00125              # not below: the scenario refuses it instead
    joined = {"plant.fish_model": "joined4"}
    assert load_scenario("scenarios/reject_doubles.toml", joined).plant.numerics.step_s == 0.00125
    with pytest.raises(InputError, match=r"gate 'gate' moves at 2\.3 m/s.*faster than 1\.5 m/s"):
        load_scenario("scenarios/reject_doubles.toml", {**joined, "plant.numerics.step_s": 0.002})  # given: kept


# ------------------------------------------------------------------------------------------ parking
def test_fish_parked_below_the_line_never_touch_each_other_or_a_gates_bin():
    """A fish waiting for its drop and one gone are parked with gravity off: parked on each other (a fish retiring
    into the place of one admitted early) or on a bin wall, their contact shot them up through the belts into the
    fish on the line.  f3 waits parked while f2, released after it was admitted, leaves the line."""
    line = two_belts([GATE])
    fishes = [fish("f1", x_m=1.0, t_s=0.05), fish("f2", x_m=3.6, t_s=1.2), fish("f3", x_m=0.5, t_s=2.1)]
    plant = Plant(line, fishes)
    bottom = device_shapes(line)[0].hinge_z_m - 0.8
    waited = []
    while plant.t_s < 2.09:
        plant.step({"c1": 0.0, "c2": 1.5}, {"gate": False})
        s = plant.state
        parked = np.flatnonzero(s.status[s.fish_of_body] != FishStatus.ON_LINE)
        assert np.all(s.pos[parked, 2] < bottom)  # below the bin
        fish_of = s.fish_of_body[parked]
        gap = np.linalg.norm(s.pos[parked, None, :] - s.pos[None, parked, :], axis=2)
        assert np.all(gap[fish_of[:, None] != fish_of[None, :]] > 0.15)  # no two fish on one place
        if s.status[2] == FishStatus.WAITING and 2 in s.member:
            waited.append(float(np.abs(s.vel[s.fish_of_body == 2]).max()))
    assert plant.state.status[1] == FishStatus.LEFT and len(waited) > 50 and max(waited) < 1e-6  # at rest
