"""One co-simulation run: preflight (every FMU described once, parameters and wiring checked), the
master that steps FMUs and plant in a defined order, the run itself and its result, and stopping on a
signal."""
