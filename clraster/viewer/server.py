"""The viewer's web server (aiohttp: HTTP and WebSocket in one well-kept library).

`ViewerServer` binds first (loopback by default) and knows its URL at once — the page, with
a random token in its query (`secrets.token_urlsafe`) — then loads the target in a worker
thread; the page shows "loading" until the scene is ready. Routes, each refusing a missing
or wrong ``token`` with 403:

* ``GET /?token=...``: the page (`clraster/viewer/page.html`, no other assets);
* ``GET /ws?token=...``: the frame stream (`clraster.viewer.protocol`);
* ``GET /shot.png?token=...``: the current view at full size as a lossless PNG
  (`Engine.screenshot`), its camera in the ``X-Clraster-Camera`` header (JSON).

One page drives the view at a time: a second stream connection while one is open is
**refused** — accepted and closed at once with code `BUSY_CODE` and a reason that says so —
and the first one keeps streaming (the page retries for a few seconds, so a reload, whose
old connection closes a moment later, still gets in). A page that goes away mid-frame is
dropped when its frame is sent; the frame in the render thread finishes and is discarded.

Frames: `frame_loop` renders whenever the page's state changed (or a reduced frame can be
refined, once the camera has rested `REFINE_AFTER_S`) and fewer than `protocol.IN_FLIGHT`
frames are being finished or await the page's acknowledgement, always from the latest
state: states that arrive while a frame renders are merged, never queued. Renders run on
one worker thread (`Engine.render`), colouring and encoding on another (`Engine.finish`),
so a frame is encoded while the next one renders; frames are sent in render order. The
event loop stays free for input.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import logging
import secrets
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

from .engine import Engine, ViewState
from .protocol import IN_FLIGHT, BadMessage, apply, pack_frame, parse
from .scene import ViewerScene, load_target

__all__ = ["BUSY_CODE", "REFINE_AFTER_S", "ViewerServer"]

log = logging.getLogger("clraster.viewer")

#: WebSocket close code for a second page while one is viewing (4000-4999: applications').
BUSY_CODE = 4409
#: Largest WebSocket message aiohttp reads at all; larger ones close the connection (1009).
_WS_MAX = 64 * 1024
#: Seconds the camera must rest before a reduced frame is rendered again at full scale: a
#: full-scale frame takes several reduced ones' time, and an input arriving while it
#: renders waits for it, so it is not started in a pause between two inputs of a walk.
REFINE_AFTER_S = 0.15


@dataclass
class _Session:
    ws: Any
    state: ViewState | None   # None until the scene is loaded
    version: int = 0          # bumped by every state change
    rendered: int = -1        # the version of the last frame rendered
    sent: int = 0             # frames sent
    acked: int = 0            # frames acknowledged
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    dropped: int = 0          # bad messages
    finishing: int = 0        # frames rendered, being coloured / encoded, not yet sent
    changed: float = 0.0      # event-loop time of the last state change


class ViewerServer:
    """Serve `target` (see `clraster.viewer.scene.load_target`) at ``size`` on
    ``host:port`` (port 0: any free one). Use ``await start()`` then ``await close()``;
    ``url`` is known after `start`. ``quality``: JPEG quality 1..100; ``budget_ms``: the
    frame time above which moving frames are rendered smaller (`Engine`)."""

    def __init__(self, target: Any, size: tuple[int, int] = (1280, 720), *,
                 host: str = "127.0.0.1", port: int = 0, quality: int = 80,
                 budget_ms: float = 40.0, device: Any = None, token: str | None = None
                 ) -> None:
        self.target = target
        self.size = size
        self.host, self.port = host, port
        self.quality, self.budget_ms, self.device = quality, budget_ms, device
        self.token = token or secrets.token_urlsafe(18)
        self.engine: Engine | None = None
        self.scene: ViewerScene | None = None
        self.load_error: str | None = None
        self.loaded = asyncio.Event()
        self._session: _Session | None = None
        # renders on one thread, colouring and encoding on another (`Engine.render`,
        # `Engine.finish`): a frame is encoded while the next one renders
        self._pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="clraster-view")
        self._finisher = concurrent.futures.ThreadPoolExecutor(
            1, thread_name_prefix="clraster-encode")
        self._runner: Any = None
        self._load_task: asyncio.Task | None = None
        self.frames_sent = 0

    # -- life cycle -----------------------------------------------------------------------

    async def start(self) -> str:
        """Bind, start loading the target, and return the page's URL."""
        from aiohttp import web

        app = web.Application(client_max_size=4096)
        app.router.add_get("/", self._page)
        app.router.add_get("/ws", self._stream)
        app.router.add_get("/shot.png", self._shot)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port)
        await site.start()
        server: Any = site._server   # an asyncio Server: the port bound (port 0: the OS's)
        self.port = server.sockets[0].getsockname()[1]
        self._load_task = asyncio.ensure_future(self._load())
        return self.url

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/?token={self.token}"

    async def _load(self) -> None:
        loop = asyncio.get_running_loop()
        w, h = self.size

        def load() -> tuple[ViewerScene, Engine]:
            vs = load_target(self.target, w, h)
            engine = Engine(vs, w, h, quality=self.quality, budget_ms=self.budget_ms,
                            device=self.device)
            engine.frame(ViewState(vs.start))   # builds the kernels, uploads the scene
            return vs, engine

        try:
            self.scene, self.engine = await loop.run_in_executor(self._pool, load)
        except Exception as exc:   # reported to the page and to the caller (`wait_loaded`)
            self.load_error = f"{type(exc).__name__}: {exc}"
            log.error("cannot load %r: %s", self.target, self.load_error)
        self.loaded.set()
        if self._session is not None:
            await self._hello(self._session)

    async def wait_loaded(self) -> None:
        """Wait until the target is loaded; ValueError with the reason if it failed."""
        await self.loaded.wait()
        if self.load_error is not None:
            raise ValueError(f"cannot load {self.target!r}: {self.load_error}")

    async def close(self) -> None:
        """Close the connections, release the port, stop the render thread (a frame being
        rendered finishes first)."""
        if self._session is not None:
            await self._session.ws.close()
        if self._runner is not None:
            await self._runner.cleanup()
        if self._load_task is not None and not self._load_task.done():
            self._load_task.cancel()
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._finisher.shutdown(wait=False, cancel_futures=True)

    # -- routes ---------------------------------------------------------------------------

    def _authorized(self, request: Any) -> bool:
        given = request.query.get("token", "")
        return secrets.compare_digest(given.encode(), self.token.encode())

    @staticmethod
    def _refuse() -> Any:
        from aiohttp import web

        return web.Response(status=403, text="403: this viewer needs the token of the URL "
                                              "that clraster view printed\n")

    async def _page(self, request: Any) -> Any:
        from aiohttp import web

        if not self._authorized(request):
            return self._refuse()
        html = resources.files(__package__).joinpath("page.html").read_text(encoding="utf-8")
        return web.Response(text=html, content_type="text/html", headers={
            "Cache-Control": "no-store", "X-Content-Type-Options": "nosniff",
            "Referrer-Policy": "no-referrer",
            "Content-Security-Policy": "default-src 'self'; script-src 'unsafe-inline'; "
                                       "style-src 'unsafe-inline'; img-src 'self' blob: data:; "
                                       "connect-src 'self'"})

    async def _shot(self, request: Any) -> Any:
        from aiohttp import web

        if not self._authorized(request):
            return self._refuse()
        if self.engine is None or self._session is None or self._session.state is None:
            return web.Response(status=409, text="409: no view to capture (open the page "
                                                 "and wait for the scene to load)\n")
        state: ViewState = self._session.state
        engine = self.engine
        pic = await asyncio.get_running_loop().run_in_executor(
            self._pool, lambda: engine.screenshot(state))
        return web.Response(body=pic.main, content_type="image/png", headers={
            "Cache-Control": "no-store",
            "X-Clraster-Camera": json.dumps(pic.header["camera"])})

    async def _stream(self, request: Any) -> Any:
        from aiohttp import WSMsgType, web

        if not self._authorized(request):
            return self._refuse()
        ws = web.WebSocketResponse(max_msg_size=_WS_MAX, heartbeat=20.0)
        await ws.prepare(request)
        if self._session is not None:
            log.info("second page refused: one page drives the view at a time")
            await ws.close(code=BUSY_CODE, message=b"another page is viewing this scene")
            return ws
        session = _Session(ws, None if self.scene is None else ViewState(self.scene.start))
        self._session = session
        loop_task = asyncio.ensure_future(self._frame_loop(session))
        try:
            if self.loaded.is_set():
                await self._hello(session)
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    self._on_message(session, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    self._drop(session, "binary messages are not accepted")
                elif msg.type == WSMsgType.ERROR:
                    break
        finally:
            loop_task.cancel()
            if self._session is session:
                self._session = None
        return ws

    async def _hello(self, session: _Session) -> None:
        if self.load_error is not None:
            await session.ws.send_str(json.dumps({"t": "error", "message": self.load_error}))
            return
        vs, engine = self.scene, self.engine
        assert vs is not None and engine is not None
        if session.state is None:
            session.state = ViewState(vs.start)
        from .engine import SCALES
        from .pictures import MODES

        await session.ws.send_str(json.dumps({
            "t": "hello", "name": vs.name, "width": engine.width, "height": engine.height,
            "inset": list(engine.inset_size()), "start": vs.start.entry(),
            "yaw": vs.start.yaw, "pitch": vs.start.pitch, "speed": vs.speed,
            "bounds": [vs.lo.tolist(), vs.hi.tolist()], "modes": list(MODES),
            "scales": list(SCALES), "triangles": vs.scene.n_faces, "in_flight": IN_FLIGHT}))
        session.wake.set()

    def _drop(self, session: _Session, why: str) -> None:
        session.dropped += 1
        log.warning("dropped a page message: %s", why)

    def _on_message(self, session: _Session, text: str) -> None:
        try:
            msg = parse(text)
            if msg["t"] == "ack":
                session.acked = max(session.acked, min(msg["n"], session.sent))
            elif session.state is not None:
                session.state = apply(session.state, msg)
                session.version += 1
                session.changed = asyncio.get_running_loop().time()
            session.wake.set()
        except BadMessage as exc:
            self._drop(session, str(exc))

    async def _frame_loop(self, session: _Session) -> None:
        loop = asyncio.get_running_loop()
        sending: asyncio.Future | None = None   # the last frame's finish-and-send
        try:
            while not session.ws.closed:
                await session.wake.wait()
                session.wake.clear()
                engine = self.engine
                if engine is None or session.state is None:
                    continue
                if session.sent + session.finishing - session.acked >= IN_FLIGHT:
                    continue   # the page is behind: wait for its ack (latest wins)
                state = session.state
                if session.version == session.rendered:
                    if not engine.needs_refine(state):
                        continue
                    rest = session.changed + REFINE_AFTER_S - loop.time()
                    if rest > 0:   # refine once the camera has rested (REFINE_AFTER_S)
                        loop.call_later(rest, session.wake.set)
                        continue
                version = session.version
                rendered = await loop.run_in_executor(self._pool, engine.render, state)
                session.rendered = version
                session.finishing += 1
                sending = asyncio.ensure_future(
                    self._finish_and_send(session, engine, rendered, sending))
                session.wake.set()   # more to do? (a newer state, a refinement)
        except (ConnectionError, asyncio.CancelledError):
            pass
        except Exception:   # a failed frame must not take the server down: log, end the page
            log.exception("frame failed")
            await session.ws.close(code=1011, message=b"frame failed; see the server log")

    async def _finish_and_send(self, session: _Session, engine: Engine, rendered: Any,
                               before: asyncio.Future | None) -> None:
        """Colour and encode ``rendered`` on the finishing thread, then send it once the
        frame ``before`` it was sent (frames go out in render order)."""
        loop = asyncio.get_running_loop()
        try:
            try:
                job = loop.run_in_executor(self._finisher, engine.finish, rendered)
            except RuntimeError:   # the server is closing: its executors are shut down
                return
            pic = await job
            if before is not None:
                await asyncio.wait([before])
            if session.ws.closed:
                return
            session.sent += 1
            pic.header["n"] = session.sent
            await session.ws.send_bytes(pack_frame(pic.header, pic.main, pic.inset))
            self.frames_sent += 1
        except (ConnectionError, asyncio.CancelledError):   # the page went away mid-frame
            pass
        except Exception:   # as in the frame loop: log, end the page
            log.exception("frame failed")
            await session.ws.close(code=1011, message=b"frame failed; see the server log")
        finally:
            session.finishing -= 1
            session.wake.set()
