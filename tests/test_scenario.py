"""Scenario files: every shipped one loads; bad ones name the file, the key and what is wrong."""

from __future__ import annotations

from pathlib import Path

import pytest

from plant.errors import InputError

from fishfmu.scenario.keys import parse_value
from fishfmu.scenario.schema import load_scenario, resolved_toml

SCENARIOS = Path(__file__).parents[1] / "scenarios"
PAPER = SCENARIOS / "paper_dump.toml"


@pytest.mark.parametrize("path", sorted(SCENARIOS.glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_scenario_loads_and_has_expect_bounds(path: Path):
    sc = load_scenario(path)
    assert sc.expect, f"{path.name} has no [expect] bounds"
    assert sc.kpi.outfeed_photoeye in [p.id for p in sc.line.photoeyes]


def test_resolved_scenario_fills_defaults_and_reads_back_identically(tmp_path: Path):
    sc = load_scenario(PAPER)
    text = resolved_toml(sc)
    assert "friction" in text and "step_s" in text  # defaults written out
    p = tmp_path / "resolved.toml"
    p.write_text(text)
    assert load_scenario(p) == sc


def test_overrides_change_values_with_toml_types():
    sc = load_scenario(PAPER, {"fish.count": parse_value("7"), "fmu[0].parameters.speed_1": parse_value("0.3"),
                               "plant.friction.fish_belt": parse_value("0.5")})
    assert sc.fish.count == 7 and sc.fmu[0].parameters["speed_1"] == 0.3 and sc.plant.friction.fish_belt == 0.5


def _write(tmp_path: Path, old: str, new: str) -> Path:
    text = PAPER.read_text()
    for o, n in zip(old.split(" | "), new.split(" | ")):
        assert o in text, o
        text = text.replace(o, n, 1)
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


BAD = [
    ("count = 18", "cuont = 18", "fish.cuont", "did you mean 'count'"),
    ("count = 18", 'count = "many"', "fish.count", "valid integer"),
    ("comm_step_s = 0.01", "comm_step_s = -1.0", "run.comm_step_s", "greater than or equal to 0.001"),
    ("comm_step_s = 0.01", "comm_step_s = 0.0055", "run.comm_step_s", "whole multiple of plant.numerics.step_s"),
    ("x_start_m = 0.0 | length_m = 2.0 | length_max_m = 0.75",  # c1 from 0.6 to 1.8, fish up to 1.4 m
     "x_start_m = 0.6 | length_m = 1.2 | length_max_m = 1.4", "fish.length_max_m", "shorter than the longest fish"),
    ('outfeed_photoeye = "pe_c4"', 'outfeed_photoeye = "pe_c5"', "kpi.outfeed_photoeye", "'pe_c5' is not a photo-eye"),
    ("x_start_m = 2.01", "x_start_m = 1.5", "line.conveyors[1].x_start_m", "overlap"),
    ("x_m = 6.43", "x_m = 7.5", "line.photoeyes[3].x_m", "outside the line"),
    ("lost = { max = 0 }", "singulaton_rate = { min = 0.1 }", "expect", "did you mean 'singulation_rate'"),
    ("lost = { max = 0 }", "fpm_out = { min = 3, max = 1 }", "expect.fpm_out.min", "is above max"),
    ('builtin = "conveyor_drive"', 'builtin = "conveyor_drives"', "fmu[1].builtin", "conveyor_drive"),
    ("[run]", "[run\n", "", "TOML syntax error"),
    ("duration_s = 90.0", "duration_s = 90.0\nspeed = 3", "run.speed", "unknown key"),
]


@pytest.mark.parametrize("old, new, key, message", BAD, ids=[b[1][:30] for b in BAD])
def test_bad_scenario_names_file_key_and_problem(tmp_path: Path, old: str, new: str, key: str, message: str):
    path = _write(tmp_path, old, new)
    with pytest.raises(InputError) as info:
        load_scenario(path)
    text = str(info.value)
    assert text.startswith(f"{path}: {key}: " if key else f"{path}: "), text  # the file, then the key to fix
    assert message in text, text
    assert "Value error" not in text  # our validators' words, not pydantic's wrapping


def test_a_byte_order_mark_is_not_part_of_the_toml(tmp_path: Path):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + PAPER.read_bytes())  # as Windows editors save UTF-8
    assert load_scenario(path).fish.count == load_scenario(PAPER).fish.count


def test_missing_file_is_an_input_error(tmp_path: Path):
    with pytest.raises(InputError, match="file not found"):
        load_scenario(tmp_path / "nope.toml")
