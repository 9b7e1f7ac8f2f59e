"""What pyproject.toml cannot say without an experimental key: the plant's C kernels (plant/sim/kernels.py says
why).  No contraction into fused multiply-adds, which round differently from numpy's separate operations: the
kernels' results are held to numpy's to the bit (tests/test_kernels.py)."""

from setuptools import Extension, setup

setup(ext_modules=[Extension("plant.sim.kernels_c", ["plant/sim/kernels_c.c"],
                             extra_compile_args=["-O2", "-ffp-contract=off"])])
