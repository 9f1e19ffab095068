"""A headless Chromium driven over the DevTools protocol, for the viewer's tests and benchmark.

No Selenium and no chromedriver: Chromium is started with ``--remote-debugging-port=0``,
its DevTools WebSocket address read from its stderr, and the protocol spoken directly
over aiohttp's WebSocket client (the same library the server uses). Only what the tests
need: open a page, evaluate JavaScript, send key and mouse events, take a screenshot.

The browser is found as ``$CLRASTER_CHROMIUM`` or the first of `BROWSERS` on the PATH
(`find_browser`); scripts/install_browser.sh installs Debian's ``chromium``.
"""

from __future__ import annotations

import asyncio
import base64
import itertools
import json
import os
import re
import shutil
import tempfile
from typing import Any

__all__ = ["BROWSERS", "Chromium", "Page", "find_browser"]

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
#: Keys the viewer understands: DOM ``code`` → (``key``, Windows virtual key code).
KEYS = {"KeyW": ("w", 87), "KeyA": ("a", 65), "KeyS": ("s", 83), "KeyD": ("d", 68),
        "KeyQ": ("q", 81), "KeyE": ("e", 69), "ArrowUp": ("ArrowUp", 38),
        "ArrowDown": ("ArrowDown", 40), "ArrowLeft": ("ArrowLeft", 37),
        "ArrowRight": ("ArrowRight", 39)}


def find_browser() -> str | None:
    """Path of a Chromium-family browser, or None."""
    env = os.environ.get("CLRASTER_CHROMIUM")
    if env:
        return shutil.which(env) or (env if os.path.isfile(env) else None)
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    return None


class Page:
    """One page (a DevTools target session) of a `Chromium`."""

    def __init__(self, browser: Chromium, session: str) -> None:
        self.browser = browser
        self.session = session

    async def call(self, method: str, **params: Any) -> dict[str, Any]:
        return await self.browser.call(method, params, session=self.session)

    async def evaluate(self, expression: str, *, await_promise: bool = False) -> Any:
        """The JSON value of a JavaScript expression (RuntimeError on a JS exception)."""
        res = await self.call("Runtime.evaluate", expression=expression, returnByValue=True,
                              awaitPromise=await_promise)
        if "exceptionDetails" in res:
            d = res["exceptionDetails"]
            raise RuntimeError(f"JavaScript: {d.get('exception', {}).get('description') or d}")
        return res["result"].get("value")

    async def wait_for(self, expression: str, timeout: float = 30.0,
                       interval: float = 0.05) -> Any:
        """Poll `expression` until it is truthy; return it (TimeoutError after `timeout`).
        A JavaScript exception counts as "not yet": right after `Chromium.open` the page may
        still be loading, before its script has defined what `expression` reads."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        error = ""
        while True:
            try:
                value = await self.evaluate(expression)
            except RuntimeError as exc:   # (named in the TimeoutError if it never passes)
                value, error = None, f" (last: {exc})"
            if value:
                return value
            if loop.time() > end:
                raise TimeoutError(f"waited {timeout} s for {expression}{error}")
            await asyncio.sleep(interval)

    async def key(self, code: str, down: bool) -> None:
        """Press (`down`) or release the key with DOM code `code` (one of `KEYS`)."""
        key, vk = KEYS[code]
        await self.call("Input.dispatchKeyEvent", type="keyDown" if down else "keyUp",
                        code=code, key=key, windowsVirtualKeyCode=vk)

    async def drag(self, x0: float, y0: float, x1: float, y1: float, steps: int = 10) -> None:
        """Drag with the left button from (x0, y0) to (x1, y1) (CSS pixels)."""
        await self.call("Input.dispatchMouseEvent", type="mousePressed", x=x0, y=y0,
                        button="left", clickCount=1, buttons=1)
        for k in range(1, steps + 1):
            x = x0 + (x1 - x0) * k / steps
            y = y0 + (y1 - y0) * k / steps
            await self.call("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y,
                            button="left", buttons=1)
            await asyncio.sleep(0.02)
        await self.call("Input.dispatchMouseEvent", type="mouseReleased", x=x1, y=y1,
                        button="left", clickCount=1, buttons=0)

    async def screenshot(self) -> bytes:
        """PNG of the page as displayed."""
        res = await self.call("Page.captureScreenshot", format="png")
        return base64.b64decode(res["data"])

    async def bytes_of(self, expression: str) -> bytes:
        """The bytes of a JavaScript Uint8Array or Blob expression."""
        b64 = await self.evaluate(
            f"(async () => {{ let v = await ({expression}); if (v instanceof Blob) "
            f"v = new Uint8Array(await v.arrayBuffer()); let s = ''; "
            f"for (let i = 0; i < v.length; i += 32768) "
            f"s += String.fromCharCode.apply(null, v.subarray(i, i + 32768)); "
            f"return btoa(s); }})()", await_promise=True)
        return base64.b64decode(b64)

    async def close(self) -> None:
        await self.browser.call("Target.closeTarget", {"targetId": self._target})

    _target: str = ""


class Chromium:
    """A headless Chromium process and its DevTools connection. ``async with Chromium() as
    b: page = await b.open(url)``. `width` × `height`: the window size."""

    def __init__(self, path: str | None = None, *, width: int = 1700, height: int = 900
                 ) -> None:
        found = path or find_browser()
        if found is None:
            raise FileNotFoundError("no Chromium found: run scripts/install_browser.sh or set "
                                    "CLRASTER_CHROMIUM to a Chromium/Chrome binary")
        self.path = found
        self.size = (width, height)
        self.proc: asyncio.subprocess.Process | None = None
        self._profile = tempfile.TemporaryDirectory(prefix="clraster-chromium-")
        self._ws: Any = None
        self._http: Any = None
        self._ids = itertools.count(1)
        self._waiting: dict[int, asyncio.Future] = {}
        self._reader: asyncio.Task | None = None

    async def __aenter__(self) -> Chromium:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def start(self) -> None:
        import aiohttp

        args = [self.path, "--headless=new", "--remote-debugging-port=0", "--no-first-run",
                "--no-default-browser-check", "--disable-extensions", "--mute-audio",
                f"--user-data-dir={self._profile.name}", "--disable-background-networking",
                "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
                "--disable-backgrounding-occluded-windows", "--disable-gpu",
                "--force-color-profile=srgb", f"--window-size={self.size[0]},{self.size[1]}",
                "about:blank"]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            args.insert(1, "--no-sandbox")   # Chromium refuses to run as root with it
        self.proc = await asyncio.create_subprocess_exec(
            *args, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
        assert self.proc.stderr is not None
        stderr = self.proc.stderr

        async def listening() -> str:
            while True:
                line = (await stderr.readline()).decode(errors="replace")
                if not line:
                    raise RuntimeError("Chromium exited before it listened")
                m = re.search(r"DevTools listening on (ws://\S+)", line)
                if m:
                    return m.group(1)

        try:
            url = await asyncio.wait_for(listening(), 60)
        except BaseException:
            await self.close()
            raise
        self._drain = asyncio.ensure_future(self._drain_stderr())
        self._http = aiohttp.ClientSession()
        self._ws = await self._http.ws_connect(url, max_msg_size=0)
        self._reader = asyncio.ensure_future(self._read())

    async def _drain_stderr(self) -> None:
        assert self.proc is not None and self.proc.stderr is not None
        while await self.proc.stderr.readline():
            pass

    async def _read(self) -> None:
        async for msg in self._ws:
            data = json.loads(msg.data)
            fut = self._waiting.pop(data.get("id", -1), None)
            if fut is not None and not fut.done():
                if "error" in data:
                    fut.set_exception(RuntimeError(f"DevTools: {data['error']}"))
                else:
                    fut.set_result(data.get("result", {}))
        for fut in self._waiting.values():
            if not fut.done():
                fut.set_exception(ConnectionError("DevTools connection closed"))

    async def call(self, method: str, params: dict[str, Any] | None = None, *,
                   session: str | None = None) -> dict[str, Any]:
        """Send one DevTools command and return its result."""
        n = next(self._ids)
        fut = asyncio.get_running_loop().create_future()
        self._waiting[n] = fut
        msg: dict[str, Any] = {"id": n, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        await self._ws.send_str(json.dumps(msg))
        return await asyncio.wait_for(fut, 120)

    async def open(self, url: str) -> Page:
        """A new page showing `url` (focused, so key events reach it)."""
        target = (await self.call("Target.createTarget", {"url": "about:blank"}))["targetId"]
        session = (await self.call("Target.attachToTarget",
                                   {"targetId": target, "flatten": True}))["sessionId"]
        page = Page(self, session)
        page._target = target
        await page.call("Page.enable")
        await page.call("Runtime.enable")
        await page.call("Page.navigate", url=url)
        await self.call("Target.activateTarget", {"targetId": target})
        await page.call("Emulation.setFocusEmulationEnabled", enabled=True)
        return page

    async def close(self) -> None:
        if self._ws is not None:
            await self._ws.close()
        if self._http is not None:
            await self._http.close()
        if self._reader is not None:
            self._reader.cancel()
        if self.proc is not None and self.proc.returncode is None:
            self.proc.terminate()
            try:
                await asyncio.wait_for(self.proc.wait(), 10)
            except asyncio.TimeoutError:
                self.proc.kill()
                await self.proc.wait()
        self._profile.cleanup()
