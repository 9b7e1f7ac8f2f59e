"""The physical singulation line: fish, conveyors, guides and photo-eyes simulated in Exudyn.

Knows nothing of FMI: its inputs are belt speeds, its outputs sensor readings and fish poses.
"""
