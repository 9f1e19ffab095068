"""The viewer in a real headless Chromium (DevTools protocol, `clraster.viewer.browser`):
the page loads and shows frames, keys and mouse drags move the camera, the frames shown are
`Renderer.render` of the camera the page reports (ids exactly, shaded JPEG within a
tolerance), the toggles change the funnel, and a recorded camera path is a camera file
``clraster render --views`` reads and replays to the same cameras.

Skipped, saying why, only where no Chromium can be found (scripts/install_browser.sh
installs one; CI has it)."""

from __future__ import annotations

import asyncio
import io
import json

import numpy as np
import pytest

pytest.importorskip("aiohttp", reason="the viewer needs aiohttp: pip install 'clraster[viewer]'")

from clraster.pipeline.renderer import Renderer  # noqa: E402
from clraster.viewer import pictures  # noqa: E402
from clraster.viewer.browser import Chromium, find_browser  # noqa: E402
from clraster.viewer.server import ViewerServer  # noqa: E402
from clraster.world.views import camera_from_entry, load_cameras  # noqa: E402

pytestmark = pytest.mark.skipif(find_browser() is None, reason=(
    "no Chromium on this machine: run scripts/install_browser.sh (apt-get install chromium) "
    "or set CLRASTER_CHROMIUM"))

W, H = 200, 120
STATS = "window.clrasterViewer.stats"


def _image(data: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


class Session:
    """One server and one browser page for the module, on their own event loop."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.run(self._start())

    def run(self, coro, timeout: float = 120.0):
        return self.loop.run_until_complete(asyncio.wait_for(coro, timeout))

    async def _start(self) -> None:
        self.server = ViewerServer("plant:20000", (W, H))
        self.url = await self.server.start()
        await self.server.wait_loaded()
        self.browser = Chromium()
        await self.browser.start()
        self.page = await self.browser.open(self.url)
        await self.page.wait_for(f"{STATS}.framesShown > 0", 60)

    async def settle(self, quiet: float = 0.5) -> dict:
        """Wait until no new frame has been shown for `quiet` seconds (the server renders
        only when something changed); return the stats."""
        p = self.page
        shown, since = -1, 0.0
        for _ in range(400):
            now = await p.evaluate(f"{STATS}.framesShown")
            if now != shown:
                shown, since = now, 0.0
            elif since >= quiet:
                return await p.evaluate(STATS)
            await asyncio.sleep(0.05)
            since += 0.05
        raise TimeoutError("frames kept coming")

    async def last_frame(self) -> tuple[dict, np.ndarray]:
        header = await self.page.evaluate("window.clrasterViewer.lastFrame.header")
        data = await self.page.bytes_of("window.clrasterViewer.lastFrame.main")
        return header, _image(data)

    async def options(self, **opts) -> dict:
        await self.page.evaluate(f"window.clrasterViewer.setOptions({json.dumps(opts)})")
        want = {k: v for k, v in opts.items() if k in ("mode",)}
        for k, v in want.items():
            await self.page.wait_for(f"window.clrasterViewer.header.{k} === {json.dumps(v)}")
        return await self.settle()

    def close(self) -> None:
        async def stop():
            await self.browser.close()
            await self.server.close()

        self.run(stop())
        self.loop.close()


@pytest.fixture(scope="module")
def s():
    session = Session()
    yield session
    session.close()


def _reported(s: Session, header: dict, **kw):
    cam = camera_from_entry(header["camera"], 0)
    return Renderer(header["width"], header["height"]).render(s.server.scene.scene, cam, **kw)


def test_keys_and_drags_move_the_camera_and_frames_follow(s):
    p = s.page
    before = s.run(s.settle())
    s.run(p.key("KeyW", True))
    s.run(asyncio.sleep(0.8))
    s.run(p.key("KeyW", False))
    after = s.run(s.settle())
    moved = np.subtract(after["camera"]["eye"], before["camera"]["eye"])
    assert np.linalg.norm(moved) > 0.5                      # walked
    assert np.dot(moved, before["camera"]["dir"]) > 0.9 * np.linalg.norm(moved)   # forwards
    assert after["framesShown"] > before["framesShown"] and after["latencyMs"] > 0
    s.run(p.drag(100, 60, 160, 60))
    turned = s.run(s.settle())
    assert turned["camera"]["yaw"] != pytest.approx(after["camera"]["yaw"])
    assert turned["camera"]["eye"] == after["camera"]["eye"]


def test_frames_shown_are_the_renderers_frames(s):
    s.run(s.options(mode="ids", lossless=True))
    header, img = s.run(s.last_frame())
    assert header["fmt"] == "png" and (header["width"], header["height"]) == (W, H)
    ref = _reported(s, header)
    assert np.array_equal(pictures.ids_from_rgb(img), ref.triangle_id)
    s.run(s.options(mode="shaded", lossless=False))
    header, img = s.run(s.last_frame())
    assert header["fmt"] == "jpeg" and header["mode"] == "shaded"
    expect = pictures.rgb(pictures.shaded_pixels(_reported(s, header).triangle_id,
                                                 s.server.engine.table))
    diff = np.abs(img.astype(int) - expect.astype(int))
    assert diff.mean() < 3.0 and np.percentile(diff, 99) < 40
    # and the canvas shows it (the browser's own decode, drawn at full size)
    shot = s.run(s.page.screenshot())
    assert _image(shot).std() > 5


def test_occlusion_toggle_empties_the_occlusion_fate(s):
    on = s.run(s.options(occlusion=True))
    h_on = s.run(s.page.evaluate("window.clrasterViewer.header"))
    s.run(s.options(occlusion=False))
    s.run(s.page.evaluate(  # nudge the camera so a frame is rendered with the new options
        "window.clrasterViewer.setCamera(window.clrasterViewer.stats.camera.eye, "
        "window.clrasterViewer.stats.camera.yaw + 1, window.clrasterViewer.stats.camera.pitch)"))
    s.run(s.settle())
    h_off = s.run(s.page.evaluate("window.clrasterViewer.header"))
    assert on["framesShown"] > 0
    assert h_on["options"]["occlusion"] and h_on["funnel"]["clusters_occlusion_culled"] > 0
    assert not h_off["options"]["occlusion"]
    assert h_off["funnel"]["clusters_occlusion_culled"] == 0
    assert h_off["fates"]["occlusion_culled"] == 0
    s.run(s.options(occlusion=True))


def test_screenshot_is_the_full_size_lossless_view(s):
    shot = s.run(s.page.evaluate(
        "window.clrasterViewer.screenshot().then(async (r) => ({camera: r.camera, "
        "size: r.blob.size, type: r.blob.type}))", await_promise=True))
    assert shot["type"] == "image/png" and shot["size"] > 100
    data = s.run(s.page.bytes_of("window.clrasterViewer.screenshot().then((r) => r.blob)"))
    img = _image(data)
    assert img.shape == (H, W, 3)


def test_recorded_path_is_a_camera_file_and_replays(s, tmp_path):
    p = s.page
    s.run(p.evaluate("document.getElementById('rec').click()"))
    s.run(p.key("KeyD", True))
    s.run(asyncio.sleep(0.6))
    s.run(p.key("KeyD", False))
    s.run(s.settle())
    s.run(p.evaluate("document.getElementById('rec').click()"))
    text = s.run(p.evaluate("window.clrasterViewer.pathJSON()"))
    path = tmp_path / "walk.json"
    path.write_text(text)
    cams = load_cameras(path)
    entries = json.loads(text)["cameras"]
    assert len(cams) >= 2 and len(cams) == len(entries)
    s.run(p.evaluate(f"window.clrasterViewer.replay({text}).then((n) => window._n = n)"))
    s.run(p.wait_for("window._n !== undefined", 60))
    final = s.run(p.evaluate(f"{STATS}.camera.entry"))
    last = entries[-1]
    assert np.allclose(final["eye"], last["eye"], atol=1e-9)
    assert np.allclose(np.subtract(final["target"], final["eye"]),
                       np.subtract(last["target"], last["eye"]), atol=1e-9)
