"""Many runs: Dask execution, several seeds of one scenario, parameter sweeps, and their statistics."""
