"""The viewer without a browser: its pictures against independent oracles (shade, a float64
distance, hand-computed pyramid texels, the ids bijection), its frames against
`Renderer.render` of the camera they report, the page-message checks, and the server
(token, second page, bad and vanishing clients, Ctrl-C) through aiohttp's client and a real
``clraster view`` process."""

from __future__ import annotations

import asyncio
import gc
import io
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("aiohttp", reason="the viewer needs aiohttp: pip install 'clraster[viewer]'")

from clraster.culling.fates import Fate  # noqa: E402
from clraster.pipeline.renderer import Renderer  # noqa: E402
from clraster.viewer import pictures  # noqa: E402
from clraster.viewer.engine import SCALES, Engine, ViewState  # noqa: E402
from clraster.viewer.protocol import BadMessage, apply, parse, unpack_frame  # noqa: E402
from clraster.viewer.scene import FlyCamera, TargetError, load_target  # noqa: E402
from clraster.viewer.server import BUSY_CODE, ViewerServer  # noqa: E402
from clraster.world.views import camera_from_entry  # noqa: E402

W, H = 160, 96


@pytest.fixture(scope="module")
def plant():
    return load_target("plant:20000", W, H)


@pytest.fixture(scope="module")
def engine(plant):
    return Engine(plant, W, H)


def _png(data: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


# -- pictures ----------------------------------------------------------------------------

def test_ids_colours_are_a_bijection():
    rng = np.random.default_rng(1)
    ids = rng.integers(-1, (1 << 24) - 1, size=(37, 53)).astype(np.int64)
    ids[0, :5] = [-1, 0, 1, (1 << 24) - 2, 12345]
    px = pictures.ids_pixels(ids)
    rgb = pictures.rgb(px)
    assert np.array_equal(pictures.ids_from_rgb(rgb), ids)
    assert np.all(rgb[ids == -1] == 0)                 # background black
    assert len(np.unique(px[ids >= 0])) == len(np.unique(ids[ids >= 0]))


def test_shaded_table_matches_shade(plant, engine):
    from clraster.output.shade import shade

    cam = plant.start.camera()
    frame = Renderer(W, H).render(plant.scene, cam)
    mine = pictures.rgb(pictures.shaded_pixels(frame.triangle_id, engine.table))
    ref = shade(frame, plant.scene, background=pictures.BACKGROUND)
    assert np.abs(mine.astype(int) - ref.astype(int)).max() <= 1


def test_depth_colours_follow_the_float64_distance():
    cam = FlyCamera((0.0, 0.0, 0.0), 0.0, 0.0, 60.0, 0.1, 100.0)
    proj = cam.camera().projection(64, 8)
    dist = np.geomspace(0.1, 90.0, 64 * 8).reshape(8, 64)   # (at far, depth rounds to 1)
    clip_z = proj[2, 2] * -dist + proj[2, 3]          # eye z = −dist
    depth = ((clip_z / dist + 1) / 2).astype(np.float32)
    depth[0, 0] = 1.0                                 # background
    got = pictures.depth_pixels(depth, proj, 0.1, 100.0)
    t = np.log(dist / 0.1) / math.log(1000.0) * (pictures.DEPTH_STEPS - 1)
    expect = pictures.rgb(pictures._DEPTH_LUT[np.floor(t).astype(int)]).astype(int)
    diff = np.abs(pictures.rgb(got).astype(int) - expect).max(axis=-1)
    assert np.array_equal(pictures.rgb(got)[0, 0], pictures.rgb(pictures._DEPTH_LUT[-1:])[0])
    diff[0, 0] = 0
    # float32 window depth near the far plane carries few bits: close there, tight nearer
    assert diff[dist < 10].max() <= 3 and diff.max() <= 25


def test_hiz_texels_are_the_farthest_depth_of_their_footprint():
    rng = np.random.default_rng(2)
    depth = rng.uniform(0.2, 0.99, (13, 21)).astype(np.float32)
    proj = FlyCamera((0.0, 0.0, 0.0), 0.0, 0.0, 60.0, 0.1, 100.0).camera().projection(21, 13)
    got, k = pictures.hiz_pixels(depth, 2, proj, 0.1, 100.0)
    assert k == 2
    expect = np.empty_like(depth)
    for y in range(13):
        for x in range(21):
            expect[y, x] = depth[y // 4 * 4:y // 4 * 4 + 4, x // 4 * 4:x // 4 * 4 + 4].max()
    assert np.array_equal(got, pictures.depth_pixels(expect, proj, 0.1, 100.0))
    assert pictures.hiz_pixels(depth, 99, proj, 0.1, 100.0)[1] == 5   # clamped: 21 → 1


def test_overdraw_ramp_saturates():
    o = np.array([[0, 1, pictures.OVERDRAW_TOP, pictures.OVERDRAW_TOP + 50]])
    px = pictures.rgb(pictures.overdraw_pixels(o))
    assert px[0, 0].sum() < 20 and np.array_equal(px[0, 2], px[0, 3])
    assert px[0, 1].sum() > px[0, 0].sum()


def test_fate_colours_are_the_demos():
    from clraster import demo

    assert pictures.FATE_COLORS == demo.FATE_COLORS


# -- camera and targets ------------------------------------------------------------------

def test_fly_camera_entry_is_its_camera():
    c = FlyCamera((1.0, 2.0, 3.0), 30.0, -20.0, 55.0, 0.05, 80.0)
    entry = json.loads(json.dumps(c.entry()))
    assert np.array_equal(camera_from_entry(entry, 0).view_projection(64, 48),
                          c.camera().view_projection(64, 48))
    assert np.allclose(c.direction, [math.cos(math.radians(-20)) * math.cos(math.radians(30)),
                                     math.sin(math.radians(-20)),
                                     math.cos(math.radians(-20)) * math.sin(math.radians(30))])
    assert c.moved((0, 0, 0), 370.0, 95.0).pitch == 89.0
    assert c.moved((0, 0, 0), 370.0, 95.0).yaw == pytest.approx(10.0)


@pytest.mark.parametrize("bad", ["plant:12", "plant:abc", "plant:1e12", "no/such/file.ply"])
def test_bad_targets_say_what_to_give(bad):
    with pytest.raises(TargetError, match="plant|file"):
        load_target(bad, W, H)


# -- page messages -----------------------------------------------------------------------

@pytest.mark.parametrize("text", [
    "garbage", "[]", '{"t": "cam"}', '{"t": "run", "code": "import os"}',
    '{"t": "cam", "seq": 1, "eye": "/etc/passwd", "yaw": 0, "pitch": 0}',
    '{"t": "cam", "seq": 1, "eye": [0, 0, NaN], "yaw": 0, "pitch": 0}',
    '{"t": "cam", "seq": 1, "eye": [0, 0, 1e30], "yaw": 0, "pitch": 0}',
    '{"t": "opts", "mode": "../../etc"}', '{"t": "opts", "path": "/tmp/x"}',
    '{"t": "opts", "occlusion": "yes"}', '{"t": "ack", "n": -1}',
    '{"t": "opts", "mode": "' + "x" * 2000 + '"}', b"\x00binary"])
def test_malformed_messages_are_refused(text):
    with pytest.raises(BadMessage):
        parse(text)


def test_messages_change_the_state(plant):
    s = ViewState(plant.start)
    s = apply(s, parse('{"t": "cam", "seq": 7, "eye": [1, 2, 3], "yaw": 45, "pitch": 10}'))
    s = apply(s, parse('{"t": "opts", "mode": "depth", "occlusion": false, "cut": 2.5}'))
    assert (s.seq, s.camera.eye, s.camera.yaw, s.camera.pitch) == (7, (1.0, 2.0, 3.0), 45.0, 10.0)
    assert (s.mode, s.occlusion, s.cut, s.frustum) == ("depth", False, 2.5, True)


# -- frames ------------------------------------------------------------------------------

def _reported_render(plant, header, **kw):
    cam = camera_from_entry(header["camera"], 0)
    return Renderer(header["width"], header["height"]).render(plant.scene, cam, **kw)


def test_ids_and_depth_frames_are_the_renderers(plant, engine):
    state = ViewState(plant.start.moved(np.add(plant.start.eye, (4.0, 0.3, 0.2)), 10.0, -5.0),
                      lossless=True)
    for mode in ("ids", "depth"):
        pic = engine.frame(replace(state, mode=mode))
        assert pic.fmt == "png" and pic.header["scale"] == 1.0
        ref = _reported_render(plant, pic.header)
        img = _png(pic.main)
        if mode == "ids":
            assert np.array_equal(pictures.ids_from_rgb(img), ref.triangle_id)
            assert (ref.triangle_id >= 0).mean() > 0.5
        else:
            cam = camera_from_entry(pic.header["camera"], 0)
            expect = pictures.depth_pixels(ref.depth, cam.projection(W, H),
                                           plant.start.near, plant.start.far)
            assert np.array_equal(img, pictures.rgb(expect))


def test_occlusion_toggle_changes_the_funnel(plant, engine):
    on = engine.frame(ViewState(plant.start, occlusion=True))
    on = engine.frame(ViewState(plant.start, occlusion=True))   # with a history
    off = engine.frame(ViewState(plant.start, occlusion=False))
    assert on.header["funnel"]["clusters_occlusion_culled"] > 0
    assert on.header["fates"]["occlusion_culled"] == on.header["funnel"][
        "clusters_occlusion_culled"]
    assert off.header["funnel"]["clusters_occlusion_culled"] == 0
    assert off.header["fates"]["occlusion_culled"] == 0
    none = engine.frame(ViewState(plant.start, occlusion=False, frustum=False, cones=False))
    assert none.header["fates"] == {"drawn": none.header["funnel"]["clusters_total"],
                                    "frustum_culled": 0, "backface_culled": 0,
                                    "occlusion_culled": 0}


def test_third_person_pane_colours_clusters_by_fate(plant, engine):
    engine.frame(ViewState(plant.start, mode="fates"))   # a history: occlusion-culled ones
    pic = engine.frame(ViewState(plant.start, mode="fates", lossless=True))
    img = _png(pic.main)
    present = {f for f, c in pictures.FATE_COLORS.items()
               if np.any(np.all(np.abs(img.astype(int) - c) <= 60, axis=-1))}
    assert {Fate.DRAWN, Fate.FRUSTUM_CULLED, Fate.OCCLUSION_CULLED} <= present
    assert np.any(np.all(img == (255, 240, 60), axis=-1))   # the frustum lines
    assert pic.inset   # the first-person picture moves to the pane


def test_pane_is_the_fates_over_the_outside_view_and_the_frustum_lines(plant):
    # oracle: the outside view rendered again, each pixel's fate through ClusterFates, and
    # the frustum's lines rendered twice (every fragment / depth-tested) as documented
    from clraster.pipeline.lines import LineRenderer, frustum_segments
    from clraster.viewer.inspect import (
        FRUSTUM_COLOR,
        FRUSTUM_HIDDEN_COLOR,
        SHADE_BASE,
        ThirdPerson,
    )

    pw, ph = 120, 72
    pane = ThirdPerson(plant, Renderer(pw, ph), LineRenderer(pw, ph))
    cam = plant.start.moved(np.add(plant.start.eye, (2.0, 0.0, 0.5)), 20.0, -4.0)
    fp = Renderer(W, H)
    fp.render(plant.scene, cam.camera(), occlusion=True)   # a history: occlusion-culled ones
    fates = fp.render(plant.scene, cam.camera(), occlusion=True, fates=True).fates
    fp_vp = cam.camera().view_projection(W, H)
    img = pictures.rgb(pane.picture(fates, fp_vp, cam.eye[1], None)[0]).astype(int)
    base = pane._base(cam.eye[1], None)
    segs = frustum_segments(fp_vp)
    oracle = LineRenderer(pw, ph)
    hidden = oracle.render(segs, base.view_proj).mask
    shown = oracle.render(segs, base.view_proj, depth=base.depth, depth_bias=1e-4).mask
    assert shown.any() and (hidden & ~shown).any()
    assert np.all(img[shown] == FRUSTUM_COLOR)
    assert np.all(img[hidden & ~shown] == FRUSTUM_HIDDEN_COLOR)
    ids = Renderer(pw, ph).render(plant.scene, base.camera,
                                  clip_planes=pane.planes(cam.eye[1], None)[0]).triangle_id
    assert np.all(img[(ids < 0) & ~hidden] == pictures.BACKGROUND)
    surf = (ids >= 0) & ~hidden
    fate = fates.id_fate(ids[surf])
    colour = np.array([pictures.FATE_COLORS[f] for f in Fate], float)[fate]
    got = img[surf]
    light = got.sum(1) / colour.sum(1)   # each pixel: its fate's colour, Lambert-shaded
    assert np.all((light > SHADE_BASE - 0.02) & (light < 1.02))
    assert np.abs(got - colour * light[:, None]).max() <= 3
    assert len(set(fate.tolist())) >= 3


def test_moving_frames_drop_resolution_not_freshness(plant):
    e = Engine(plant, W, H, budget_ms=1e-3)   # nothing fits: the smallest scale
    a = e.frame(ViewState(plant.start, seq=1))
    cam2 = plant.start.moved(np.add(plant.start.eye, (0.5, 0, 0)), 0.0, 0.0)
    b = e.frame(ViewState(cam2, seq=2))
    assert a.header["scale"] == 1.0 and b.header["scale"] < 1.0
    assert b.header["camera"]["eye"] == list(cam2.eye) and b.header["seq"] == 2
    assert e.needs_refine(ViewState(cam2, seq=2))
    c = e.frame(ViewState(cam2, seq=2))
    assert c.header["scale"] == 1.0 and not e.needs_refine(ViewState(cam2, seq=2))


def test_every_scale_is_a_fresh_renderers_frame(plant):
    # the renderers of the reduced scales share the full-size one's device state and
    # occlusion history: each frame must still be what a renderer of its own would draw
    e = Engine(plant, W, H)
    cam = plant.start
    for k, s in enumerate([*SCALES, *SCALES[::-1]]):
        cam = cam.moved(np.add(cam.eye, (0.3, 0.0, 0.1)), cam.yaw + 3.0, cam.pitch)
        pic = e.frame(ViewState(cam, mode="ids", lossless=True, seq=k), s)
        assert pic.header["scale"] == s
        ref = _reported_render(plant, pic.header)
        assert np.array_equal(pictures.ids_from_rgb(_png(pic.main)), ref.triangle_id), s


def _rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _live(cls) -> int:
    gc.collect()
    return sum(1 for o in gc.get_objects() if type(o) is cls)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/statm")
def test_memory_stays_flat_across_scales_modes_and_the_pane():
    # a renderer per scale (and per pane) held its own copy of the scene's geometry pool
    # and stage buffers: ~100 MiB each for this plant, ~450 MiB for the 10M one
    from clraster.pipeline.drawlist import GeometryPool
    from clraster.pipeline.stages.chain import StageChain

    vs = load_target("plant:2M", W, H)
    pools, chains = _live(GeometryPool), _live(StageChain)
    e = Engine(vs, W, H)
    cam = vs.start
    e.frame(ViewState(cam, inset=True), 1.0)   # warm-up: the scene uploaded, buffers grown
    rss0 = _rss_mib()
    for k in range(3 * len(SCALES)):
        cam = cam.moved(np.add(cam.eye, (0.2, 0.0, 0.0)), cam.yaw + 2.0, cam.pitch)
        mode = "fates" if k % 3 == 2 else "shaded"   # fates: a pane at the view's size
        e.frame(ViewState(cam, mode=mode, seq=k), SCALES[k % len(SCALES)])
    grown = _rss_mib() - rss0
    assert _live(GeometryPool) - pools == 1   # one host copy of the scene's geometry
    assert _live(StageChain) - chains == 1    # one set of device stage buffers
    assert grown < 40, f"RSS grew {grown:.0f} MiB over frames at every scale"


# -- the server --------------------------------------------------------------------------

async def _serve_and(check):
    server = ViewerServer("plant:20000", (W, H))
    url = await server.start()
    await server.wait_loaded()
    try:
        await check(server, url.split("/?")[0], server.token)
    finally:
        await server.close()


def test_token_second_page_bad_messages_and_vanishing_pages():
    import aiohttp

    async def check(server, base, token):
        async with aiohttp.ClientSession() as http:
            # a wrong last character (not "x" whatever the token ends with: a token that
            # ended in "x" made this the right one, 1 run in 64)
            wrong = token[:-1] + ("y" if token[-1] == "x" else "x")
            for path in ("/", "/ws", "/shot.png"):
                for q in ("", "?token=", "?token=" + wrong):
                    r = await http.get(base + path + q)
                    assert r.status == 403, (path, q)
            assert (await http.get(f"{base}/?token={token}")).status == 200
            ws = await http.ws_connect(f"{base}/ws?token={token}")
            hello = json.loads((await ws.receive()).data)
            assert hello["t"] == "hello" and hello["width"] == W
            header, main, _ = unpack_frame((await ws.receive()).data)
            await ws.send_str(json.dumps({"t": "ack", "n": header["n"]}))
            second = await http.ws_connect(f"{base}/ws?token={token}")
            await second.receive()
            assert second.close_code == BUSY_CODE
            for bad in ("garbage", '{"t": "opts", "path": "/etc"}', "x" * 5000):
                await ws.send_str(bad)
            await ws.send_bytes(b"\x00" * 10)
            await ws.send_str(json.dumps({"t": "opts", "mode": "depth"}))
            header, main, _ = unpack_frame((await ws.receive()).data)
            assert header["mode"] == "depth"                    # still served
            shot = await http.get(f"{base}/shot.png?token={token}")
            assert shot.status == 200 and _png(await shot.read()).shape == (H, W, 3)
            # a page that vanishes mid-frame: a new camera, then gone before the frame
            await ws.send_str(json.dumps({"t": "ack", "n": header["n"]}))
            await ws.send_str(json.dumps({"t": "cam", "seq": 5, "eye": [1.0, 1.7, 10.0],
                                          "yaw": 0, "pitch": 0}))
            await ws.close()
            await asyncio.sleep(0.5)
            ws = await http.ws_connect(f"{base}/ws?token={token}")   # healthy, free again
            assert json.loads((await ws.receive()).data)["t"] == "hello"
            header, main, _ = unpack_frame((await ws.receive()).data)
            assert header["n"] == 1 and main[:2] == b"\xff\xd8"   # a JPEG
            await ws.close()

    asyncio.run(check_with_timeout(check))


def test_stream_follows_the_camera_in_order_then_refines_at_full_scale():
    import aiohttp

    async def check(server, base, token):
        server.engine.budget_ms = 1e-3   # every moving frame reduced
        async with aiohttp.ClientSession() as http:
            ws = await http.ws_connect(f"{base}/ws?token={token}")
            assert json.loads((await ws.receive()).data)["t"] == "hello"
            headers = [unpack_frame((await ws.receive()).data)[0]]
            eye = np.array(server.scene.start.eye)
            for k in range(1, 7):   # a walk: each camera a new frame
                eye = eye + (0.3, 0.0, 0.0)
                await ws.send_str(json.dumps({"t": "cam", "seq": k, "eye": eye.tolist(),
                                              "yaw": 10.0 * k, "pitch": 0}))
                # two cameras before the first ack: the next frame renders while one is
                # being encoded or sent
                if k % 2 == 0:
                    for _ in range(2):
                        h = unpack_frame((await ws.receive()).data)[0]
                        headers.append(h)
                        await ws.send_str(json.dumps({"t": "ack", "n": h["n"]}))
            while headers[-1]["seq"] != 6 or headers[-1]["scale"] != 1.0:   # at rest
                h = unpack_frame((await ws.receive()).data)[0]
                headers.append(h)
                await ws.send_str(json.dumps({"t": "ack", "n": h["n"]}))
            await ws.close()
        ns = [h["n"] for h in headers]
        seqs = [h["seq"] for h in headers]
        assert ns == list(range(1, len(ns) + 1))          # sent in render order
        assert seqs == sorted(seqs) and seqs[-1] == 6      # never an older camera
        # a new camera's first frame is reduced (moving); a camera at rest gets one more,
        # at full scale (the last one here)
        pairs = list(zip(headers[:-1], headers[1:], strict=True))
        new = [h for prev, h in pairs if h["seq"] != prev["seq"]]
        assert len(new) >= 3 and all(h["scale"] < 1.0 for h in new)
        assert all(h["scale"] == 1.0 for prev, h in pairs if h["seq"] == prev["seq"])
        assert headers[-1]["camera"]["eye"] == eye.tolist()

    asyncio.run(check_with_timeout(check))


async def check_with_timeout(check):
    await asyncio.wait_for(_serve_and(check), 120)


def _free(port: int) -> bool:
    """Whether a server could listen on `port` now (as servers do, with SO_REUSEADDR: a
    connection of the old one in TIME_WAIT does not hold the port)."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
            s.listen()
        except OSError:
            return False
    return True


def test_command_prints_the_url_at_once_and_stops_on_ctrl_c():
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    proc = subprocess.Popen([sys.executable, "-m", "clraster.cli", "view", "example",
                             "--size", "96x64", "--no-browser"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    try:
        t0 = time.monotonic()
        line = proc.stdout.readline()   # a pipe: flushed at once, before the scene loads
        m = re.fullmatch(r"http://127\.0\.0\.1:(\d+)/\?token=([\w-]{20,})\n", line)
        assert m, line
        port = int(m.group(1))
        assert time.monotonic() - t0 < 30
        while "ready" not in (err := proc.stderr.readline()):
            assert err, "the viewer exited before it was ready"
        assert not _free(port)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(60) == 130
        assert _free(port)
    finally:
        if proc.poll() is None:
            proc.kill()


def test_command_refuses_a_bad_target_with_exit_1():
    proc = subprocess.run([sys.executable, "-m", "clraster.cli", "view", "plant:12",
                           "--no-browser"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    assert "plant:N needs a whole number of triangles" in proc.stderr


def test_view_from_python_serves_and_stops(capsys):
    import urllib.request

    import clraster

    v = clraster.view("example", size=(64, 48), open_browser=False).wait_loaded(120)
    try:
        assert capsys.readouterr().out.strip() == v.url
        with urllib.request.urlopen(v.url, timeout=30) as r:
            assert r.status == 200 and b"clrasterViewer" in r.read()
        assert 'iframe src="' + v.url in v._repr_html_()
    finally:
        v.stop()
    assert _free(v.server.port)
