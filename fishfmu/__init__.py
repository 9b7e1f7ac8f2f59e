"""Co-simulation of a salmon singulation line: FMUs, scenarios, the master and the command line."""

import os as _os
import sys as _sys

if _os.environ.get("FISHFMU_SESSION") and "--multiprocessing-fork" in _sys.argv:
    # a worker process (Dask, a process pool) of a fishfmu command, importing the command's main
    # module first thing: Ctrl-C to the process group is the command's to handle; it stops the
    # workers in order (see fishfmu.session.session)
    import signal as _signal
    _signal.signal(_signal.SIGINT, _signal.SIG_IGN)
