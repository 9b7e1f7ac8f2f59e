"""Benchmarks, each reached as ``fishfmu bench ...``: results go to files, never into tests."""
