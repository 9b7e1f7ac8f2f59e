"""What a scenario file says: its schema (keys, types, units, defaults), ``--set`` overrides, the wiring
between the plant and the FMUs, and the generated scenario reference (docs/scenario-reference.md)."""
