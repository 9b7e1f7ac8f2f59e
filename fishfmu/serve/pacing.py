"""Real-time pacing of ``fishfmu serve --realtime FACTOR``: how late each step starts against the wall clock.

Step k is due at ``start + k dt / FACTOR`` on the monotonic clock; the lateness of each step's start against its
due time is measured, and a step starting more than one communication step (of wall time) late counts as an
overrun.  When the median lateness of the last 100 steps exceeds a step, the line cannot keep up.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

BEHIND_AFTER_STEPS = 100
"""The steps over which the median lateness says whether the line keeps up."""


@dataclass
class Pacing:
    """Lateness of each step's start against its due time (real time), s."""

    factor: float
    comm_step_s: float
    lateness_s: list[float] = field(default_factory=list)
    lag_max_s: float = 0.0
    late_steps: int = 0

    def record(self, lateness_s: float) -> None:
        """A step started ``lateness_s`` after it was due."""
        self.lateness_s.append(lateness_s)
        self.lag_max_s = max(self.lag_max_s, lateness_s)
        self.late_steps += lateness_s > self.step_wall_s

    def clear(self) -> None:
        self.lateness_s.clear()
        self.lag_max_s, self.late_steps = 0.0, 0

    @property
    def lag_s(self) -> float:
        """How late the last step started."""
        return self.lateness_s[-1] if self.lateness_s else 0.0

    @property
    def step_wall_s(self) -> float:
        """Wall time per communication step."""
        return self.comm_step_s / self.factor

    def recent_median_s(self) -> float | None:
        """The median lateness of the last BEHIND_AFTER_STEPS steps, once there are that many."""
        if len(self.lateness_s) < BEHIND_AFTER_STEPS:
            return None
        return float(np.median(self.lateness_s[-BEHIND_AFTER_STEPS:]))

    def summary(self) -> dict[str, Any]:
        late = np.asarray(self.lateness_s) if self.lateness_s else np.zeros(1)
        return {"factor": self.factor, "steps": len(self.lateness_s),
                "lateness_p50_s": round(float(np.percentile(late, 50)), 6),
                "lateness_p99_s": round(float(np.percentile(late, 99)), 6),
                "lateness_max_s": round(float(late.max()), 6),
                "overruns": self.late_steps,
                "overrun_rule": "a step that starts more than one communication step (of wall time, at the pace then) "
                                "after it was due"}
