"""``serve --live HOST:PORT``: the running line in 3D in a browser, for a commissioning engineer beside the PLC.

An HTTP server (tornado, on the serving event loop) gives two things, both read-only (any other method is 405):

- ``/``: the replay's page (:mod:`fishfmu.output.replay`, the same renderer) in live mode: the line, its parts
  and devices and the fish's outlines, without recorded frames;
- ``/frame``: the latest frame as JSON: the step and time, every body's position and orientation (w, x, y, z),
  each fish's status, each belt's speed and travel, each device's position, each photo-eye's state, and the
  run's status (state, lag, late steps, real-time factor reached, fish counts).  The page asks for it 20 times a
  second.

Frames are taken from the line at most :data:`FRAME_RATE_HZ` times a second, between two steps (the line is not
stepping then), and the latest one is kept; the HTTP server only hands out that one.  A slow or absent browser
therefore never paces or slows the line: frames nobody fetched are dropped.  A reset() may change the fish (a
new seed): the page is made anew and the frame says which page it belongs to (``page``), so an open page reloads.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import time
from typing import Any, Awaitable, Callable

import numpy as np
from tornado.httpserver import HTTPServer
from tornado.web import Application, RequestHandler

from plant.contract.line import Line
from plant.errors import InputError
from plant.sim.recorder import body_outlines
from plant.sim.rotations import matrix_to_quaternion
from plant.sim.state import PlantState

from fishfmu.output.replay import Packer, line_header, render_html
from fishfmu.serve.options import listen_error

FRAME_RATE_HZ = 20.0
"""Frames taken from the line per second of wall time at most (and the page's requests per second)."""
STATUS_KEYS = ("time_s", "run_state", "lag_s", "lag_max_s", "late_steps", "realtime_factor",
               "realtime_factor_reached", "fish_waiting", "fish_on_line", "fish_left", "fish_rejected")
"""The run's status in a frame: the root object's variables of the same names (``fishfmu.<key>``)."""


def live_page(line: Line, state: PlantState, name: str, page: int) -> str:
    """The live page of ``line`` with the fish of the plant's ``state`` (their outlines), no frames; ``page``
    numbers it (a frame of another page makes the browser reload)."""
    packer = Packer([], {})
    header = line_header(line, name, "live", body_outlines(state), packer)
    header["live"] = {"frame": "frame", "page": page, "rate_hz": FRAME_RATE_HZ}
    header["arrays"] = packer.index
    return render_html(header, packer.blob())


def frame_of(c: Any, line: Line, travel_m: np.ndarray, values: dict[str, Any], page: int) -> dict[str, Any]:
    """The frame of the co-simulation ``c`` of ``line`` now (see the module docstring); ``values`` what the address
    space shows (:func:`fishfmu.serve.address_space.shown_values`)."""
    state = c.plant.state
    pos, rot = state.body_poses()
    visible = np.all(np.isfinite(pos), axis=1)
    quat = np.zeros((len(pos), 4))
    quat[:, 0] = 1.0
    if visible.any():
        quat[visible] = matrix_to_quaternion(rot[visible])
    pos = np.where(visible[:, None], pos, 0.0)
    out = state.outputs
    conveyors = [cv.id for cv in line.conveyors]
    status = {k: _plain(values.get(f"fishfmu.{k}")) for k in STATUS_KEYS}
    return {
        "page": page, "step": int(c.steps), "t_s": float(c.t_s),
        "pos": np.round(pos, 6).reshape(-1).tolist(), "quat": np.round(quat, 6).reshape(-1).tolist(),
        "status": state.status.astype(int).tolist(),
        "belt_speed": [float(out.belt_speed_mps.get(cv, 0.0)) if out else 0.0 for cv in conveyors],
        "belt_travel": [round(float(v), 6) for v in travel_m],
        "device_p": [] if state.device_position is None else [float(v) for v in np.clip(state.device_position, 0, 1)],
        "blocked": dict(out.photoeyes) if out else {},
        "run": status,
    }


def _plain(v: Any) -> Any:
    """A status value as JSON can hold it (NaN as null)."""
    if isinstance(v, (np.integer, np.floating)):
        v = v.item()
    return None if isinstance(v, float) and not math.isfinite(v) else v


class LiveView:
    """The live page and its latest frame, served over HTTP at ``host:port`` (see the module docstring)."""

    def __init__(self, host: str, port: int, line: Line, name: str) -> None:
        self.host, self.port, self.line, self.name = host, port, line, name
        self.html = ""
        self.frame = b"{}"
        self.page = 0
        self.captured_step = -1
        self.captured_state: str | None = None
        self._cosim: Any = None
        self._last_wall = -math.inf
        self._server: HTTPServer | None = None
        self._task: asyncio.Task | None = None

    def due(self) -> bool:
        """A frame may be taken now (the last one is 1/FRAME_RATE_HZ old)."""
        return time.monotonic() - self._last_wall >= 1.0 / FRAME_RATE_HZ

    def stale(self, c: Any, values: dict[str, Any]) -> bool:
        """The latest frame is not of the line's latest step, of its run (a reset) or of its state (a pause)."""
        return c is not None and (c is not self._cosim or c.steps != self.captured_step
                                  or values.get("fishfmu.run_state") != self.captured_state)

    def capture(self, c: Any, values: dict[str, Any], travel_m: np.ndarray) -> None:
        """Take the frame of ``c`` (between two steps: the caller holds the line) with each belt's ``travel_m`` (the
        stripes' phase, summed step by step by :class:`fishfmu.serve.publication.Publication`); a new run (a reset)
        makes a new page."""
        if c is not self._cosim:
            self._cosim, self.page = c, self.page + 1
            self.html = live_page(self.line, c.plant.state, self.name, self.page)
        frame = frame_of(c, self.line, travel_m, values, self.page)
        self.frame = json.dumps(frame, separators=(",", ":"), allow_nan=False).encode()
        self.captured_step, self._last_wall = c.steps, time.monotonic()
        self.captured_state = values.get("fishfmu.run_state")

    async def start(self, stale: Callable[[], bool], catch_up: Callable[[], Awaitable[None]]) -> None:
        """Listen (on the serving event loop); a port taken since it was checked is bad input naming --live.
        Every 1/FRAME_RATE_HZ s, when ``stale()`` (the line has stepped or changed state since the last frame and is
        not stepping),
        ``catch_up()`` takes its frame."""
        logging.getLogger("tornado.access").setLevel(logging.ERROR)  # no line per request on the console
        app = Application([(r"/", _Page, {"live": self}), (r"/frame", _Frame, {"live": self})])
        self._server = HTTPServer(app)
        try:
            self._server.listen(self.port, address=self.host)
        except OSError as exc:
            raise InputError(listen_error(self.host, self.port, exc), where="--live") from None

        async def follow() -> None:
            while True:
                await asyncio.sleep(1.0 / FRAME_RATE_HZ)
                if stale() and self.due():
                    await catch_up()
        self._task = asyncio.create_task(follow())

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
        if self._server is not None:
            self._server.stop()
            await self._server.close_all_connections()


class _Page(RequestHandler):
    def initialize(self, live: LiveView) -> None:
        self.live = live

    def get(self) -> None:
        self.set_header("Content-Type", "text/html; charset=utf-8")
        self.set_header("Cache-Control", "no-store")
        self.write(self.live.html)


class _Frame(RequestHandler):
    def initialize(self, live: LiveView) -> None:
        self.live = live

    def get(self) -> None:
        self.set_header("Content-Type", "application/json")
        self.set_header("Cache-Control", "no-store")
        self.write(self.live.frame)
