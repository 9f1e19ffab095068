"""Time the per-pixel passes of render_shaded (SSAO, FXAA) at 1920x1080: the device passes
(`clraster.pipeline.stages.post.DevicePasses`) and, with ``--numpy``, their NumPy twins.

    python bench/post_passes.py               # median of 9 after 2 warm-ups, ms
    python bench/post_passes.py --rounds 15 --numpy
    python bench/post_passes.py --kernels     # also SSAO's kernels one by one (events)

The frame: a floor with boxes on it (tests/test_post_device.py's scene) seen from above so
that nearly every pixel is covered; SSAO with the default taps (`SSAO.samples`, or
``--taps``) and a 0.4 radius (≈ 30 px); FXAA over the smooth-shaded image (edge-rich).
Times are wall-clock per call, as render_shaded pays them (uploads, launches and read-back
included); ``--kernels`` adds each SSAO kernel's device time from OpenCL profiling events
(a second DevicePasses on a profiling queue). The machine is shared: compare rows of one
run, not across runs.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import pyopencl as cl
import trimesh

import clraster
from clraster.output import post
from clraster.output.shade import pixel_normals, render_shaded
from clraster.pipeline.stages.post import DevicePasses, device_passes


def scene() -> clraster.Mesh:
    floor = trimesh.creation.box(extents=(8, 0.02, 8))
    floor.apply_translation((0, -0.01, 0))
    parts = [floor]
    rng = np.random.default_rng(3)
    for _ in range(40):
        b = trimesh.creation.box(extents=rng.uniform(0.2, 0.8, 3))
        b.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
        b.apply_translation(rng.uniform(-2.5, 2.5, 3) * (1, 0.3, 1) + (0, 0.5, 0))
        parts.append(b)
    return clraster.Mesh.from_trimesh(trimesh.util.concatenate(parts))


def timed(fn, rounds: int, warm: int = 2) -> tuple[float, float]:
    for _ in range(warm):
        fn()
    ts = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return min(ts), statistics.median(ts)


def ssao_kernel_times(ctx: cl.Context, call, rounds: int) -> dict[str, list[float]]:
    """ms per kernel of `call(passes)` (an SSAO call) over `rounds` calls after 2 warm-ups,
    from profiling events of a DevicePasses whose queue profiles."""
    dev = DevicePasses(ctx)
    dev.queue = cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)
    names = {"k_prepare": "ssao_prepare", "k_ssao": "ssao", "k_upsample": "ssao_upsample"}
    events: dict[str, cl.Event] = {}
    def recorded(k, name: str):
        def launch(*args):
            events[name] = k(*args)
            return events[name]
        return launch

    for attr, name in names.items():
        setattr(dev, attr, recorded(getattr(dev, attr), name))
    times: dict[str, list[float]] = {name: [] for name in names.values()}
    for i in range(rounds + 2):
        call(dev)
        if i >= 2:
            for name, e in events.items():
                times[name].append((e.profile.end - e.profile.start) * 1e-6)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--numpy", action="store_true", help="also time the NumPy twins")
    ap.add_argument("--taps", type=int, default=post.SSAO.samples, help="SSAO taps per pixel")
    ap.add_argument("--kernels", action="store_true",
                    help="also SSAO's kernels one by one (profiling events)")
    a = ap.parse_args()
    w, h = a.width, a.height
    r = clraster.Renderer(w, h)
    mesh = scene()
    cam = clraster.Camera.look_at((0.0, 4.5, 3.0), (0, 0.2, 0), near=0.5, far=30.0)
    frame = r.render(mesh, cam)
    n = pixel_normals(frame, mesh).astype(np.float32)
    vp = cam.view_projection(w, h)
    params = post.SSAO(radius=0.4, samples=a.taps).checked(1.0)
    img = render_shaded(r, mesh, cam, smooth=True)   # uint8 (H, W, 3): FXAA runs on 8 bits
    dev = device_passes(r)
    assert dev is not None
    cov = float(np.mean(frame.triangle_id >= 0))
    print(f"{w}x{h}, {cov:.0%} covered, ssao {params.samples} taps r={params.radius}")
    rows = [("ssao device", lambda: dev.ssao(frame.depth, n, vp, False, params)),
            ("fxaa device", lambda: dev.fxaa(img))]
    if a.numpy:
        rows += [("ssao numpy", lambda: post.ssao(frame.depth, n, vp, False, params)),
                 ("fxaa numpy", lambda: post.fxaa(img))]
    for name, fn in rows:
        lo, med = timed(fn, a.rounds)
        print(f"{name:12s} min {lo:8.2f} ms  median {med:8.2f} ms")
    if a.kernels:
        times = ssao_kernel_times(r.context, lambda d: d.ssao(frame.depth, n, vp, False, params),
                                  a.rounds)
        for name, ts in times.items():
            print(f"  {name:14s} min {min(ts):8.2f} ms  median {statistics.median(ts):8.2f} ms")


if __name__ == "__main__":
    main()
