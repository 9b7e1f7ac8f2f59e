"""Co-simulation of a salmon singulation line: FMUs, scenarios, the master and the command line."""

import os as _os
import sys as _sys

# One BLAS thread unless the user asked for more, set before numpy loads OpenBLAS: the product's matrices are
# small (tens of rows), where BLAS threads gain nothing, and on a busy two-core host (two test processes, two
# diagnose workers, a run beside serve) OpenBLAS's spinning threads made the same analysis 4x slower (guide
# wear's tests: 39 s against 9 s beside two busy cores, 2026-11-28). Workers inherit it.
for _name in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_name, "1")

if _os.environ.get("FISHFMU_SESSION") and "--multiprocessing-fork" in _sys.argv:
    # a worker process (Dask, a process pool) of a fishfmu command, importing the command's main
    # module first thing: Ctrl-C to the process group is the command's to handle; it stops the
    # workers in order (see fishfmu.session.session)
    import signal as _signal
    _signal.signal(_signal.SIGINT, _signal.SIG_IGN)
