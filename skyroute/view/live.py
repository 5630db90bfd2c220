"""The live view's server: a page on 127.0.0.1 and a WebSocket that streams the flight to it.

:class:`ViewHub` holds what the page shows, in named *channels*; :class:`LiveView` serves the page and its
vendored three.js (``static/``) with aiohttp, in its own thread and event loop. Publishers (the flight feed in
:mod:`skyroute.view.feed`, or the CLI) call the hub from any thread: a call takes one lock for a few
microseconds and never waits on a browser. Each browser connection has its own coroutine that, ``rate_hz``
times a second, sends what changed since it last sent; a browser that reads slowly just gets fewer, fresher
updates (intermediate states are dropped, append-only data is never lost). The only module that imports aiohttp.

Protocol (JSON text messages, server to page; ``PROTOCOL_VERSION``):

``{"type": "scene", "protocol": 1, ...}``
    Once per connection: the hub's scene, as the CLI published it: ``home`` ``{lat_deg, lon_deg}``, ``boxes``
    ``[[north_m, east_m, alt_m, half_north_m, half_east_m, half_alt_m], ...]`` (the map's obstacles, map frame),
    ``altitude_m``, ``safety_m``, ``goal`` ``[north_m, east_m]``, ``start`` (or null).
``{"type": "update", "seq": n, <channel>: ..., ...}``
    Only the channels that changed since this connection's previous update. Two kinds:

    *latest-value* channels (:meth:`ViewHub.set`): ``state`` (``time_s``, ``mission_state``, ``armed``, ``mode``,
    ``link_ok``, ``vehicle`` ``{north_m, east_m, altitude_m, heading_rad}`` or null, ``speed_mps``,
    ``climb_mps``, ``distance_to_go_m``), ``plan`` (``{"id": k, "waypoints": [[north_m, east_m, altitude_m],
    ...]}``; a new id is a replan, and the page keeps earlier plans drawn faintly), and, reserved for sensing
    and exploration, ``known_area`` (``{north_offset_m, east_offset_m, cell_m, rows, cols, known}`` with
    ``known`` a row-major string of ``0``/``1`` per cell, north index first) and ``frontiers``
    (``[[north_m, east_m], ...]``);

    *append-only* channels (:meth:`ViewHub.extend`), sent as ``{"from": index, "items": [...]}`` so that a
    page can check it missed nothing: ``track`` (``[time_s, north_m, east_m, altitude_m]`` as flown),
    ``events`` (``{"time_s", "text"}``: mission transitions), and, reserved for sensing, ``obstacles``
    (discovered boxes, same rows as the scene's ``boxes``).

A channel the page does not know is ignored by it, so adding one breaks no page.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from skyroute.view import DEFAULT_VIEW_PORT

log = logging.getLogger(__name__)

PROTOCOL_VERSION = 1
LATEST_CHANNELS = ("state", "plan", "known_area", "frontiers")
APPEND_CHANNELS = ("track", "events", "obstacles")


class ViewError(RuntimeError):
    """The view could not be served: ``host:port`` and the operating system's reason."""


def json_safe(value: Any) -> Any:
    """``value`` with NaN and infinities as ``None`` (JSON has neither), numpy numbers and arrays as Python ones.

    >>> json_safe({"a": float("nan"), "b": [1.5, float("inf")]})
    {'a': None, 'b': [1.5, None]}
    """
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return json_safe(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@dataclass
class _Cursor:
    """What one connection has been sent: versions of latest-value channels, lengths of append-only ones."""

    versions: dict[str, int] = field(default_factory=dict)
    lengths: dict[str, int] = field(default_factory=dict)
    seq: int = 0


class ViewHub:
    """The view's data, published from any thread and read by the server's connections.

    ``scene`` is sent once to each connection; see the module docstring for the channels.
    """

    def __init__(self, scene: dict | None = None) -> None:
        self._lock = threading.Lock()
        self._scene = json_safe(scene or {})
        self._latest: dict[str, Any] = {}
        self._versions: dict[str, int] = {}
        self._append: dict[str, list] = {name: [] for name in APPEND_CHANNELS}

    def set_scene(self, scene: dict) -> None:
        with self._lock:
            self._scene = json_safe(scene)

    def set(self, channel: str, value: Any) -> None:
        """Replace a latest-value channel (``state``, ``plan``, ``known_area``, ``frontiers``, or a new one)."""
        if channel in self._append:
            raise ValueError(f"{channel} is an append-only channel; use extend()")
        value = json_safe(value)
        with self._lock:
            self._latest[channel] = value
            self._versions[channel] = self._versions.get(channel, 0) + 1

    def extend(self, channel: str, items: Iterable[Any]) -> None:
        """Append to an append-only channel (``track``, ``events``, ``obstacles``, or a new one)."""
        if channel in self._latest:
            raise ValueError(f"{channel} is a latest-value channel; use set()")
        items = json_safe(list(items))
        with self._lock:
            self._append.setdefault(channel, []).extend(items)

    def latest(self, channel: str) -> Any:
        with self._lock:
            return self._latest.get(channel)

    def length(self, channel: str) -> int:
        with self._lock:
            return len(self._append.get(channel, ()))

    def scene_message(self) -> dict:
        with self._lock:
            return {"type": "scene", "protocol": PROTOCOL_VERSION, **self._scene}

    def update_for(self, cursor: _Cursor) -> dict | None:
        """The update message for a connection at ``cursor`` (advanced), or ``None`` if nothing changed."""
        message: dict[str, Any] = {}
        with self._lock:
            for channel, version in self._versions.items():
                if cursor.versions.get(channel) != version:
                    message[channel] = self._latest[channel]
                    cursor.versions[channel] = version
            for channel, items in self._append.items():
                start = cursor.lengths.get(channel, 0)
                if len(items) > start:
                    message[channel] = {"from": start, "items": items[start:]}
                    cursor.lengths[channel] = len(items)
        if not message:
            return None
        cursor.seq += 1
        return {"type": "update", "seq": cursor.seq, **message}


def static_dir() -> Path:
    """The page, its script and the vendored three.js, shipped inside the package."""
    return Path(str(resources.files("skyroute.view") / "static"))


class LiveView:
    """Serve ``hub`` on ``http://host:port/`` (page) and ``/ws`` (the stream) from a thread of its own.

    ``port`` 0 picks a free port; :attr:`url` says which. ``host`` is loopback only (127.0.0.1) unless a caller
    insists. Use as a context manager or call :meth:`start` / :meth:`close`.

    Raises
    ------
    ViewError
        From :meth:`start`, when the address cannot be bound (in use, not permitted).
    """

    def __init__(self, hub: ViewHub, port: int = DEFAULT_VIEW_PORT, *, host: str = "127.0.0.1",
                 rate_hz: float = 20.0) -> None:
        if not 0 <= port <= 65535:
            raise ViewError(f"view port must be 0..65535, got {port}")
        self.hub, self.host, self.port, self.rate_hz = hub, host, port, rate_hz
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner = None
        self._sockets: set = set()

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    @property
    def addresses(self) -> list:
        """The ``(host, port)`` addresses the server listens on (empty before :meth:`start`)."""
        return list(self._runner.addresses) if self._runner is not None else []

    # ------------------------------------------------------------------------------------------ lifecycle
    def start(self) -> LiveView:
        from aiohttp import web

        self._loop = asyncio.new_event_loop()
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/scene.json", self._scene_json)
        app.router.add_static("/static/", static_dir(), follow_symlinks=False)
        app.on_shutdown.append(self._close_sockets)
        self._runner = web.AppRunner(app, access_log=None, shutdown_timeout=1.0)
        try:
            self._loop.run_until_complete(self._runner.setup())
            site = web.TCPSite(self._runner, self.host, self.port)
            self._loop.run_until_complete(site.start())
        except OSError as exc:
            self._loop.run_until_complete(self._runner.cleanup())
            self._loop.close()
            raise ViewError(f"cannot serve the view on {self.host}:{self.port}: {exc.strerror or exc}") from None
        self.port = self._runner.addresses[0][1]
        self._thread = threading.Thread(target=self._loop.run_forever, name="live-view", daemon=True)
        self._thread.start()
        log.info("live view on %s", self.url)
        return self

    def close(self) -> None:
        """Close every connection and stop the server thread. Safe to call twice."""
        loop, self._loop = self._loop, None
        if loop is None:
            return
        try:
            asyncio.run_coroutine_threadsafe(self._runner.cleanup(), loop).result(timeout=5.0)
        except Exception as exc:  # noqa: BLE001 - shutting down: say so, never raise over the mission's outcome
            log.warning("live view shutdown: %r", exc)
        loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        loop.close()

    def __enter__(self) -> LiveView:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------- handlers
    async def _index(self, request):
        from aiohttp import web

        return web.FileResponse(static_dir() / "index.html", headers={"Cache-Control": "no-store"})

    async def _scene_json(self, request):
        from aiohttp import web

        return web.json_response(self.hub.scene_message())

    async def _websocket(self, request):
        from aiohttp import web

        ws = web.WebSocketResponse(heartbeat=10.0)
        await ws.prepare(request)
        self._sockets.add(ws)
        cursor, period_s = _Cursor(), 1.0 / self.rate_hz
        try:
            await ws.send_str(json.dumps(self.hub.scene_message(), allow_nan=False))
            reader = asyncio.ensure_future(self._drain(ws))
            while not ws.closed and not reader.done():
                message = self.hub.update_for(cursor)
                if message is not None:
                    await ws.send_str(json.dumps(message, allow_nan=False))  # waits for this browser only
                await asyncio.sleep(period_s)
            reader.cancel()
        except (ConnectionResetError, asyncio.CancelledError):
            pass
        finally:
            self._sockets.discard(ws)
        return ws

    @staticmethod
    async def _drain(ws) -> None:
        """Read (and ignore) what the page sends, so that a close from the page is noticed."""
        from aiohttp import WSMsgType

        async for msg in ws:
            if msg.type in (WSMsgType.ERROR, WSMsgType.CLOSE):
                break

    async def _close_sockets(self, app) -> None:
        from aiohttp import WSCloseCode

        for ws in list(self._sockets):
            await ws.close(code=WSCloseCode.GOING_AWAY, message=b"the flight is over")
