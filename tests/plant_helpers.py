"""Small builders shared by the plant tests: a straight line and a fish of given length."""

from __future__ import annotations

from plant.fish.fish_data import length_regressions
from plant.contract.line import Line
from plant.fish.population import FishSpec


def straight_line(*belts: tuple[str, float, float, float], guide_width_m: float = 0.5,
                  photoeyes: tuple[tuple[str, float, float], ...] = ()) -> Line:
    """Belts as (id, x_start, length, z_top), all 0.5 m wide."""
    return Line.model_validate({
        "guide_width_m": guide_width_m,
        "conveyors": [{"id": i, "x_start_m": x, "length_m": length, "width_m": max(0.5, guide_width_m), "z_top_m": z}
                      for i, x, length, z in belts],
        "photoeyes": [{"id": i, "x_m": x, "z_m": z} for i, x, z in photoeyes]})


def fish(fish_id: str = "f01", length_m: float = 0.6, x_m: float = 0.6, y_m: float = 0.0, yaw_rad: float = 0.0,
         t_s: float = 0.05, z_m: float = 0.01, side: int = 1) -> FishSpec:
    """A fish of the regression's size for its length, dropped flat from just above the belt."""
    reg = length_regressions()
    return FishSpec(fish_id, length_m, float(reg.height_m(length_m)), float(reg.width_m(length_m)),
                    float(reg.weight_kg(length_m)), 24.0, t_s, x_m, y_m, yaw_rad, z_m, side)
