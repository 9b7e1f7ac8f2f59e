"""Values of ``[plant]`` at dotted paths, read back and written as scenario fragments (TOML) a user can keep."""

from __future__ import annotations

from plant.sim.params import PlantParams


def plant_value(p: PlantParams, path: str) -> float:
    """The value at a dotted path in ``[plant]`` (``friction.fish_belt``)."""
    obj = p
    for part in path.split("."):
        obj = getattr(obj, part)
    return float(obj)


def plant_tables(values: dict[str, float]) -> str:
    """Values at dotted paths in ``[plant]`` as TOML tables (``[plant.friction]`` ...), in the given order."""
    tables: dict[str, list[str]] = {}
    for path, value in values.items():
        *table, key = path.split(".")
        tables.setdefault(".".join(["plant", *table]), []).append(f"{key} = {value:.4g}\n")
    return "".join(f"[{t}]\n" + "".join(lines) for t, lines in tables.items())
