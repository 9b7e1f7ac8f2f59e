"""The order in which the FMUs step, from their connections (see :mod:`fishfmu.scenario.wiring`, "Coupling").

Under Gauss-Seidel each FMU steps after the FMUs it reads from, so that it sees their values of this step; where
FMUs feed each other, the one listed first steps first.  A cycle of outputs declared as direct feedthrough (an
algebraic loop) cannot be ordered: an input error.
"""

from __future__ import annotations

from typing import Any

from plant.errors import InputError


def direct_feedthrough(model_description) -> set[str]:
    """Outputs whose value after a step depends directly on an input at that time, as declared in
    the modelDescription's ModelStructure (an output without a ``dependencies`` list is read as
    depending on its FMU's state: in co-simulation, outputs come out of doStep)."""
    inputs = {v.name for v in model_description.modelVariables if v.causality == "input"}
    out = set()
    for u in model_description.outputs:
        if u.dependencies and any(d.name in inputs for d in u.dependencies):
            out.add(u.variable.name)
    return out


def stepping_order(names: list[str], connections: list[Any], scenario_file: str | None,
                   feedthrough: dict[str, set[str]] | None = None) -> list[str]:
    """FMUs ordered so that each comes after the FMUs it reads from (``connections``: the wiring's
    :class:`~fishfmu.scenario.wiring.Connection` list, ``feedthrough``: each FMU's :func:`direct_feedthrough`).

    Where FMUs feed each other in a cycle, the one listed first in the scenario steps first and
    sees the others' values from the previous step (as a PLC reads its inputs one scan late).  A
    cycle made only of outputs declared as direct feedthrough is an algebraic loop: an error.
    """
    feedthrough = feedthrough or {}
    edges = {(c.source.component, c.target.component) for c in connections
             if c.source.component in names and c.target.component in names and c.source.component != c.target.component}
    direct = {(c.source.component, c.target.component) for c in connections
              if (c.source.component, c.target.component) in edges
              and c.source.variable in feedthrough.get(c.source.component, set())}
    reject_loops(names, direct, scenario_file)
    remaining = list(names)
    incoming = {n: {a for a, b in edges if b == n} for n in names}
    order: list[str] = []
    while remaining:
        ready = [n for n in remaining if not (incoming[n] & set(remaining))]
        pick = ready[0] if ready else remaining[0]  # a cycle: the first listed goes first
        order.append(pick)
        remaining.remove(pick)
    return order


def reject_loops(names: list[str], direct: set[tuple[str, str]], scenario_file: str | None) -> None:
    state: dict[str, int] = {}

    def visit(n: str, path: list[str]) -> None:
        if state.get(n) == 2:
            return
        if state.get(n) == 1:
            cycle = path[path.index(n):] + [n]
            raise InputError(f"algebraic loop: {' -> '.join(cycle)} (every output in it is declared to depend "
                             "directly on an input); such a cycle cannot be ordered: break it or use "
                             "run.coupling = \"jacobi\"", file=scenario_file, where="wiring.connections")
        state[n] = 1
        for a, b in sorted(direct):
            if a == n:
                visit(b, path + [n])
        state[n] = 2

    for n in names:
        visit(n, [])
