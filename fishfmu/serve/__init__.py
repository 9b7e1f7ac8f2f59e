"""``fishfmu serve``: the line as an OPC UA server, for a PLC to commission against (asyncua).

The command itself is :func:`fishfmu.commands.serve`: it checks the options and the scenario, opens the run's
folder, serves the line until its run ends and writes the run like any run, through the same lifecycle as
``fishfmu run`` (:class:`fishfmu.output.run_folder.RunFolder`).  This package is what it serves:

- :mod:`fishfmu.serve.options`: the endpoint (loopback only unless ``allow_remote``; a port of 1-65535 that is
  free), the real-time factor (0.001 to 1000), certificates and keys, all checked before the output folder is
  made (bad options are exit 2 naming the option);
- :mod:`fishfmu.serve.model`: the information model, made once from the scenario: an object per component (each
  conveyor, photo-eye, camera and device under ``plant``, each FMU instance) with its signals (types, units, ranges,
  states, descriptions) and the line table's parameters; :mod:`fishfmu.serve.signal_list` writes it as CSV;
- :mod:`fishfmu.serve.address_space`: the model's nodes in the namespace ``urn:fishfmu`` as OPC UA clients look for
  them (AnalogItemType, EngineeringUnits and EURange in namespace 0, TwoStateDiscreteType, an enumeration), the
  methods (``step(n)``, ``start()``, ``pause()``, ``resume()``, ``set_speed(factor)``, ``stop()``, ``reset([seed])``)
  with their arguments checked, the run's events.  Only the inputs of ``[opcua] inputs`` are writable; a write an
  input cannot take and a method called with bad arguments get an OPC UA status;
- :mod:`fishfmu.serve.modbus_map` and :mod:`fishfmu.serve.modbus`: the same signals over Modbus TCP
  (``--modbus``), its register map and lockstep step-request register;
- :mod:`fishfmu.serve.live`: ``--live``, a web page showing the running line in 3D (the replay's renderer) and its
  status, fed with frames taken between steps (read-only; never pacing the line);
- :mod:`fishfmu.serve.status`: the run's states (waiting, running, paused, finished, stopped, failed) and its
  clock against the wall (lag, late steps, the real-time factor reached), the grace time after the end;
- :mod:`fishfmu.serve.publication`: the line's step observer, and what it publishes after each batch of steps to
  the address space and its status nodes, the Modbus server and the live view (why after a batch: there);
- :mod:`fishfmu.serve.line`: the co-simulation stepped in a worker thread, in lockstep (a client's ``step(n)``)
  or in real time (:mod:`fishfmu.serve.pacing`: p50/p99/max lateness and overruns go to ``run_info.json``,
  ``served``); the run ends at ``run.duration_s``, a client's ``stop()`` or a signal;
- :mod:`fishfmu.serve.server`: the asyncua server, its identity (``--user``, the password from
  ``FISHFMU_OPCUA_PASSWORD``) and security (Basic256Sha256 SignAndEncrypt with certificates, else NoSecurity).

Importing this package does not import asyncua (about 0.4 s): the option checks here are what the command line
needs before it serves; :mod:`fishfmu.serve.line` brings the server.
"""

from fishfmu.serve.options import (DEFAULT_ENDPOINT, PASSWORD_ENV, Certificates, endpoint_problem, listen_problem,
                                   options_problem, realtime_problem)

__all__ = ["DEFAULT_ENDPOINT", "PASSWORD_ENV", "Certificates", "endpoint_problem", "listen_problem",
           "options_problem", "realtime_problem"]
