"""``clraster view TARGET``: walk through a scene in a browser; and `view` from Python.

The command binds the server, prints one line with the page's URL at once (flushed, also
into a pipe), opens a browser unless ``--no-browser`` (or none is found), loads the target
and serves until Ctrl-C. Exit codes: 0 never in practice (it serves until stopped), 1 the
target cannot be loaded or the port cannot be bound (one line on stderr), 2 bad arguments,
130 interrupted (Ctrl-C: connections closed and the port released first).

From Python, ``clraster.view(target)`` starts the same server on a background thread and
returns a `Viewer` (``.url``, ``.stop()``); in Jupyter it also displays the page inline (an
IFrame of the URL; the kernel needs no display and no GL, the browser shows the frames —
over SSH, forward the port).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
import threading
import webbrowser
from collections.abc import Sequence
from typing import Any

from ..base.checks import parse_size

__all__ = ["Viewer", "main", "view"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="clraster view",
        description="Walk through TARGET in a web browser: frames rendered by clraster with "
                    "frustum, cone and occlusion culling, streamed to a page with fly-through "
                    "controls, display modes, the culling funnel and a third-person view of "
                    "what was culled.")
    p.add_argument("target", metavar="TARGET",
                   help="a mesh or scene file trimesh reads, 'plant' (the procedural power "
                        "plant, 1M triangles), 'plant:N' (N triangles, e.g. plant:10M) or "
                        "'example'")
    p.add_argument("--size", type=parse_size, default=(1280, 720), metavar="WxH",
                   help="frame size in pixels (default 1280x720)")
    p.add_argument("--port", type=_port, default=0, metavar="N",
                   help="TCP port (default 0: any free port)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1, this machine only; the "
                        "URL's token is still required from elsewhere)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser")
    p.add_argument("--quality", type=_quality, default=80, metavar="Q",
                   help="JPEG quality 1..100 of the stream (default 80)")
    return p


def _port(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        v = -1
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port number 0..65535, got {text!r}")
    return v


def _quality(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        v = -1
    if not 1 <= v <= 100:
        raise argparse.ArgumentTypeError(f"expected a JPEG quality 1..100, got {text!r}")
    return v


async def _serve(args: argparse.Namespace) -> int:
    from .server import ViewerServer

    server = ViewerServer(args.target, args.size, host=args.host, port=args.port,
                          quality=args.quality)
    try:
        url = await server.start()
        print(url, flush=True)
        if not args.no_browser and _has_gui():
            threading.Thread(target=webbrowser.open, args=(url,), daemon=True).start()
        await server.wait_loaded()
        print(f"clraster view: {server.scene.name if server.scene else args.target} ready "
              f"({args.size[0]}x{args.size[1]}); Ctrl-C stops", file=sys.stderr, flush=True)
        await asyncio.Event().wait()   # until cancelled (Ctrl-C)
        return 0
    finally:
        await server.close()


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``clraster view`` with `argv` (default ``sys.argv[1:]``); returns the exit code."""
    parser = _parser()
    try:
        args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        import aiohttp  # noqa: F401
    except ImportError:
        print("clraster view: error: the viewer needs aiohttp: pip install 'clraster[viewer]'",
              file=sys.stderr)
        return 1
    logging.basicConfig(level=logging.WARNING, format="clraster view: %(message)s")
    try:
        return asyncio.run(_serve(args))
    except KeyboardInterrupt:
        print("clraster view: interrupted", file=sys.stderr, flush=True)
        return 130
    except (ValueError, OSError) as exc:
        print(f"clraster view: error: {exc}", file=sys.stderr)
        return 1


class Viewer:
    """A viewer running on a background thread (`view`). ``url``: the page; ``server``: the
    `ViewerServer`; ``stop()`` closes it and releases the port."""

    def __init__(self, target: Any, size: tuple[int, int], host: str, port: int,
                 **kw: Any) -> None:
        from .server import ViewerServer

        self._loop = asyncio.new_event_loop()
        self.server = ViewerServer(target, size, host=host, port=port, **kw)
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True,
                                        name="clraster-viewer")
        self._thread.start()
        self.url: str = asyncio.run_coroutine_threadsafe(self.server.start(),
                                                         self._loop).result()

    def wait_loaded(self, timeout: float | None = None) -> Viewer:
        """Block until the target is loaded (ValueError if it could not be)."""
        asyncio.run_coroutine_threadsafe(self.server.wait_loaded(), self._loop).result(timeout)
        return self

    def stop(self) -> None:
        """Close the server and its thread."""
        if self._thread.is_alive():
            asyncio.run_coroutine_threadsafe(self.server.close(), self._loop).result(30)
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(30)

    def _repr_html_(self) -> str:
        return (f'<iframe src="{self.url}" width="100%" height="{self.server.size[1] + 40}" '
                f'style="border:0"></iframe>')

    def __repr__(self) -> str:
        return f"Viewer({self.url})"


def view(target: Any, *, size: tuple[int, int] = (1280, 720), host: str = "127.0.0.1",
         port: int = 0, open_browser: bool | None = None, quality: int = 80) -> Viewer:
    """Serve `target` (a path, "plant", "plant:N", "example", or a Mesh / Scene / trimesh
    object) for a browser and return the running `Viewer` at once (the target loads in the
    background). In Jupyter the page is displayed inline; elsewhere a browser is opened
    unless ``open_browser=False``. Its URL is also printed (one line)."""
    v = Viewer(target, size, host, port, quality=quality)
    print(v.url, flush=True)
    shell = _ipython()
    if shell is not None:
        from IPython.display import display

        display(v)
    elif open_browser or (open_browser is None and _has_gui()):
        webbrowser.open(v.url)
    return v


def _has_gui() -> bool:
    """Whether a graphical browser can be opened here: on a server without a display,
    `webbrowser` would start a console browser in the terminal instead."""
    import os

    return sys.platform in ("darwin", "win32") or bool(
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _ipython() -> Any:
    """The running IPython kernel shell, or None."""
    mod = sys.modules.get("IPython")
    shell = mod.get_ipython() if mod is not None and hasattr(mod, "get_ipython") else None
    return shell if shell is not None and hasattr(shell, "kernel") else None
