"""The browser viewer measured in a real headless Chromium: frames shown per second and
input-to-display latency while walking, per target and size (`window.clrasterViewer`'s
stats, read over the DevTools protocol), the server's frame time, its memory over the walk,
and the JPEG encoders side by side.

    python bench/viewer.py                           # plant:10M 720p + 1080p, dragon 720p
    python bench/viewer.py --runs plant:10M@1280x720 --seconds 20
    python bench/viewer.py --runs plant:10M@1280x720 --soak 600 --rss-series rss.jsonl
                                                     # memory each second over 10 minutes
    python bench/viewer.py --encoders                # Pillow vs simplejpeg vs PyTurboJPEG
    python bench/viewer.py --screenshot docs/viewer.png

A walk: the page loads, two seconds settle, then W is held (the plant: down the first
corridor at the default 3 m/s; a mesh: towards it at its default speed; with --soak, back
and forth, the mouse turning the view every second); fps = frames shown during the walk /
its length,
latency = the page's input → first frame showing it (p50, p95); the server's frame time
and scale are those of every frame shown (the page's ``shown`` list); CPU = cores used
during the walk by the server process alone and by Chromium's processes. Browser and
server share the machine's cores. The results go to stdout as a Markdown table (copy into
bench/README.md's log with the date and the machine's load).
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DRAGON = ROOT.parent / "shared" / "meshes" / "stanford_dragon_vrip.ply"
DEFAULT_RUNS = ("plant:10M@1280x720", "plant:10M@1920x1080", "dragon@1280x720")


def _rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _cpu_s(pids: list[int], children: bool = True) -> float:
    """CPU seconds (user + system, threads included) used so far by the processes
    ``pids`` and (``children``) their descendants still alive."""
    import psutil

    total, seen = 0.0, set()
    for pid in pids:
        try:
            root = psutil.Process(pid)
            procs = [root, *(root.children(recursive=True) if children else [])]
        except psutil.NoSuchProcess:
            continue
        for p in procs:
            if p.pid in seen:
                continue
            seen.add(p.pid)
            try:
                t = p.cpu_times()
            except psutil.NoSuchProcess:
                continue
            total += t.user + t.system
    return total


def _target(name: str) -> str:
    return str(DRAGON) if name == "dragon" else name


async def walk(run: str, seconds: float, soak: float = 0.0, screenshot: Path | None = None
               ) -> dict:
    from clraster.viewer.browser import Chromium
    from clraster.viewer.server import ViewerServer

    name, size = run.split("@")
    w, h = (int(v) for v in size.split("x"))
    server = ViewerServer(_target(name), (w, h))
    url = await server.start()
    t0 = time.perf_counter()
    await server.wait_loaded()
    load_s = time.perf_counter() - t0
    out: dict = {"run": run, "load_s": load_s}
    async with Chromium(width=w + 320, height=h + 60) as browser:
        page = await browser.open(url)
        await page.wait_for("window.clrasterViewer.stats.framesShown > 0", 120)
        await asyncio.sleep(2.0)
        if screenshot is not None:
            await page.key("KeyW", True)
            await asyncio.sleep(1.5)
            await page.key("KeyW", False)
            await asyncio.sleep(1.0)
            screenshot.write_bytes(await page.screenshot())
        rss = [_rss_mib()]
        assert browser.proc is not None
        cpu0 = (_cpu_s([os.getpid()], False), _cpu_s([browser.proc.pid]))
        n0 = await page.evaluate("window.clrasterViewer.stats.framesShown")
        l0 = await page.evaluate("window.clrasterViewer.latencies.length")
        s0 = await page.evaluate("window.clrasterViewer.shown.length")
        await page.key("KeyW", True)
        start = time.perf_counter()
        length = max(seconds, soak)
        turn = 1
        while time.perf_counter() - start < length:
            await asyncio.sleep(1.0)
            if soak:   # walk back and forth along the corridor, turning
                turn = -turn
                await page.drag(200, 200, 200 + 40 * turn, 200, steps=4)
            rss.append(_rss_mib())
            if soak and int(time.perf_counter() - start) % 20 == 0:
                await page.key("KeyW", False)
                await page.key("KeyS", True)
                await asyncio.sleep(5.0)
                await page.key("KeyS", False)
                await page.key("KeyW", True)
        elapsed = time.perf_counter() - start
        await page.key("KeyW", False)
        n1 = await page.evaluate("window.clrasterViewer.stats.framesShown")
        cpu1 = (_cpu_s([os.getpid()], False), _cpu_s([browser.proc.pid]))
        lat = await page.evaluate(f"window.clrasterViewer.latencies.slice({l0})")
        shown = np.array(await page.evaluate(f"window.clrasterViewer.shown.slice({s0})"),
                         np.float64).reshape(-1, 2)
    await server.close()
    lat = np.array(lat, np.float64)
    out.update(fps=(n1 - n0) / elapsed, p50=float(np.percentile(lat, 50)),
               p95=float(np.percentile(lat, 95)), frames=n1 - n0,
               frame_ms=float(np.median(shown[:, 1])),
               frame_p95=float(np.percentile(shown[:, 1], 95)),
               scale=float(np.median(shown[:, 0])),
               full_share=float(np.mean(shown[:, 0] == 1.0)),
               rss_start=rss[0], rss_end=rss[-1], rss_max=max(rss), rss=rss,
               cpu_server=(cpu1[0] - cpu0[0]) / elapsed, cpu_browser=(cpu1[1] - cpu0[1]) / elapsed)
    return out


def encoders(reps: int = 30) -> None:
    """Encode times of one shaded plant frame at 720p and 1080p, each encoder."""
    for w, h in ((1280, 720), (1920, 1080)):
        _encoders_at(w, h, reps)


def _encoders_at(w: int, h: int, reps: int) -> None:
    from PIL import Image

    from clraster.pipeline.renderer import Renderer
    from clraster.viewer import pictures
    from clraster.viewer.scene import load_target

    if True:
        vs = load_target("plant:1000000", w, h)
        frame = Renderer(w, h).render(vs.scene, vs.start.camera())
        t = pictures.face_table(vs.scene)
        px = pictures.shaded_pixels(frame.triangle_id, t)
        rgb = pictures.rgb(px)
        rgbx = px.view(np.uint8).reshape(h, w, 4)

        def pillow() -> bytes:
            b = io.BytesIO()
            Image.fromarray(rgb).save(b, "JPEG", quality=80)
            return b.getvalue()

        cands = {"Pillow": pillow}
        try:
            import simplejpeg

            cands["simplejpeg (RGBX in)"] = lambda: simplejpeg.encode_jpeg(
                rgbx, quality=80, colorspace="RGBX", colorsubsampling="420", fastdct=True)
        except ImportError:
            pass
        try:
            from turbojpeg import TJPF_RGB, TJSAMP_420, TurboJPEG

            tj = TurboJPEG()
            cands["PyTurboJPEG"] = lambda: tj.encode(rgb, quality=80, pixel_format=TJPF_RGB,
                                                     jpeg_subsample=TJSAMP_420)
        except (ImportError, RuntimeError, OSError) as exc:
            print(f"PyTurboJPEG: not measured ({exc})".splitlines()[0])

        def colour() -> None:
            pictures.shaded_pixels(frame.triangle_id, t)

        timings = {}
        for name, fn in [*cands.items(), ("colour table lookup", colour)]:
            fn()
            ts = []
            for _ in range(reps):
                t0 = time.perf_counter()
                fn()
                ts.append((time.perf_counter() - t0) * 1e3)
            timings[name] = statistics.median(ts)
        from clraster.output.shade import shade

        ts = []
        for _ in range(3):
            t0 = time.perf_counter()
            shade(frame, vs.scene)
            ts.append((time.perf_counter() - t0) * 1e3)
        timings["clraster.shade.shade (host)"] = statistics.median(ts)
        for name, ms in timings.items():
            print(f"| {w}x{h} | {name} | {ms:.2f} ms |")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", nargs="+", default=list(DEFAULT_RUNS),
                   help="TARGET@WxH, TARGET: plant:N, dragon, example or a mesh path")
    p.add_argument("--seconds", type=float, default=15.0)
    p.add_argument("--soak", type=float, default=0.0, metavar="S",
                   help="walk back and forth for S seconds and report memory")
    p.add_argument("--rss-series", type=Path, metavar="FILE",
                   help="append each run's per-second RSS series (JSON lines) to FILE")
    p.add_argument("--encoders", action="store_true", help="only the encoder comparison")
    p.add_argument("--screenshot", type=Path, help="save the page (first run) as PNG")
    args = p.parse_args(argv)
    if args.encoders:
        print("| size | step | median |\n|---|---|---:|")
        encoders()
        return 0
    print("| run | fps shown | latency p50 | p95 | server frame median (p95) | scale median | "
          "full-size share | CPU server / browser (cores) | RSS start → end (max) | load |")
    print("|---|---:|---:|---:|---:|---:|---:|---|---|---:|")
    for k, run in enumerate(args.runs):
        r = asyncio.run(walk(run, args.seconds, args.soak,
                             args.screenshot if k == 0 else None))
        print(f"| {r['run']} | {r['fps']:.1f} | {r['p50']:.0f} ms | {r['p95']:.0f} ms | "
              f"{r['frame_ms']:.1f} ({r['frame_p95']:.0f}) ms | {r['scale']:.3g} | "
              f"{r['full_share']:.0%} | "
              f"{r['cpu_server']:.2f} / {r['cpu_browser']:.2f} | "
              f"{r['rss_start']:.0f} → {r['rss_end']:.0f} ({r['rss_max']:.0f}) MiB | "
              f"{r['load_s']:.1f} s |", flush=True)
        if args.rss_series is not None:   # one line per run: the RSS each second (MiB)
            with args.rss_series.open("a") as f:
                f.write(json.dumps({"run": r["run"], "rss_mib": [round(v, 1) for v in r["rss"]]})
                        + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
