"""``clraster demo``: the built-in plant, first person, with a culling inspector.

Builds :func:`clraster.scenes.plant`, renders it from the first-person corridor camera
(:func:`clraster.scenes.plant_inside_camera`) with frustum, normal-cone and two-phase
occlusion culling for a few frames (the first one builds the kernels and has no visibility
history; the later ones reuse it), and writes into ``--out``:

* ``shaded.png``: flat Lambert shading (`clraster.shade.render_shaded`, its frame rendered
  with the same culling) lit by a sun (a directional `clraster.shade.Light`) and a lamp over
  the corridor (a spot light), both with shadow maps, and screen-space ambient occlusion
  (`AO_RADIUS`). The corridor has storeys above it, so the sun's shadow map leaves it in
  shadow (lit by the ambient term only); the lamp lights it;
* ``depth.png``: eye distance on a log scale over the covered pixels, with a colour bar
  in metres;
* ``overdraw.png``: fragments tested per pixel (the depth-test work, after the tile Hi-Z)
  as a heat map, with a colour bar;
* ``inspector.png``: the same ground floor from a third-person camera above and behind,
  everything above a horizontal user clip plane `INSPECTOR_CUT` over the floor cut away
  (``render(..., clip_planes=...)``: instances crossing the plane are cut open, not
  dropped), every cluster coloured by its fate in the first-person frame (drawn,
  frustum-culled, back-face (cone) culled, occlusion-culled), lightly shaded, with the
  first-person view frustum drawn as lines.

It prints the culling funnel (`FrameStats`), the frame times, the fate counts and the
files written. The lettering, panels, colour ramps and colour bars in the images come from
`clraster.output.annotate` (text in Pillow's default font).
Exit codes: 0 success, 1 the output could not be written or no OpenCL device, 2 bad
arguments.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import numpy as np

from .base.checks import parse_positive_int, parse_size
from .culling.fates import Fate
from .output.annotate import (
    DEPTH_RAMP,
    HEAT,
    TEXT_HEIGHT,
    colorbar,
    draw_text,
    nice_step,
    panel,
    ramp,
    text_width,
    ui_scale,
)
from .world.camera import Camera
from .world.mesh import Mesh
from .world.scene import Scene

__all__ = ["FATE_COLORS", "main"]

#: RGB of each fate in the inspector (and its legend).
FATE_COLORS = {
    Fate.DRAWN: (70, 200, 90),
    Fate.FRUSTUM_CULLED: (80, 130, 230),
    Fate.BACKFACE_CULLED: (250, 170, 40),
    Fate.OCCLUSION_CULLED: (215, 55, 65),
}
FATE_LABELS = {
    Fate.DRAWN: "drawn",
    Fate.FRUSTUM_CULLED: "frustum culled",
    Fate.BACKFACE_CULLED: "back-face culled (normal cone)",
    Fate.OCCLUSION_CULLED: "occlusion culled (hi-z)",
}
#: Inspector: the first-person frustum, depth-tested (bright) and hidden parts (dim).
FRUSTUM_COLOR = (255, 240, 60)
FRUSTUM_HIDDEN_COLOR = (165, 150, 70)
INSPECTOR_BACKGROUND = (28, 30, 36)
#: The inspector cuts the plant with a horizontal clip plane this height (metres) over the
#: first-person storey's floor, keeping what lies below it: the ceiling pipes, lamps, slabs
#: and storeys above go, walls and machines that reach through the plane are cut open, so
#: the corridor and the rooms around it can be seen from above.
INSPECTOR_CUT = 2.6
#: The sun of ``shaded.png``: the direction its light travels (world, y up).
SUN_DIRECTION = (0.45, -1.0, 0.3)
#: The lamp of ``shaded.png``: a spot light this far ahead of and above the eye (metres, x
#: along the corridor), shining forward and down within LAMP_CONE degrees.
LAMP_OFFSET = (4.0, 1.3, 0.0)
LAMP_DIRECTION = (1.0, -0.9, 0.15)
LAMP_CONE = 60.0
#: ``shaded.png``'s ambient occlusion radius in metres (the plant's scale: pipes, corners,
#: machine feet), instead of render_shaded's default share of the whole plant's diagonal.
AO_RADIUS = 0.5
#: Largest ``--triangles``: the demo holds the plant flattened into one world mesh
#: (`world_mesh`, for shading) plus the renderer's per-triangle buffers, about 300 bytes of
#: host memory per triangle over a base of about 0.2 GiB (peak RSS measured: 0.5 GiB at 1M,
#: 1.35 GiB at 4M, 2.5 GiB at 8M triangles at 640x360; 2.6 GiB at 8M at 1920x1080), so the
#: cap peaks near 15 GiB, well under a 24 GiB machine; without it a typo such as 10**12
#: would run until memory ran out. Checked when the arguments are parsed, before anything
#: is built.
MAX_TRIANGLES = 50_000_000

# -- images ----------------------------------------------------------------------------

def world_mesh(scene: Scene) -> Mesh:
    """All instances of `scene` as one world-space mesh whose face indices are the scene's
    triangle ids (``face_base[instance] + face``), e.g. for `clraster.shade.shade`."""
    verts, faces = [], []
    v0 = 0
    for inst in scene.instances:
        m = inst.transform
        v = np.asarray(inst.mesh.vertices, np.float64) @ m[:3, :3].T + m[:3, 3]
        verts.append(v)
        faces.append(np.asarray(inst.mesh.faces, np.int64) + v0)
        v0 += v.shape[0]
    if not verts:
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    return Mesh(np.concatenate(verts), np.concatenate(faces))


def depth_picture(depth: Any, projection: np.ndarray, *, reversed_z: bool | None = None
                  ) -> np.ndarray:
    """RGB (H, W, 3) uint8: eye distance (metres, from the depth buffer through the
    projection's z rows) on a log scale between the nearest and farthest covered pixel,
    with a colour bar; background black.

    `depth` is a `clraster.Frame` (read by its own ``reversed_z``) or a bare (H, W) buffer
    whose convention `reversed_z` gives: None/False standard window depth ``(z/w + 1)/2``
    (covered where < 1), True reversed-Z ``(1 − z/w)/2`` (covered where > 0); as
    `clraster.shade.depth_image`, which raises ValueError for a flag contradicting the
    frame."""
    from .output.shade import _depth_buffer

    d, rev = _depth_buffer(depth, reversed_z)
    finite = np.isfinite(d)
    covered = finite & (d > 0.0) if rev else finite & (d < 1.0)
    out = np.zeros(d.shape + (3,), np.uint8)
    if not covered.any():
        return out
    # NDC z from each convention directly (1 − 2d keeps reversed-Z's far precision)
    zn = 1.0 - 2.0 * d[covered] if rev else 2.0 * d[covered] - 1.0
    p22, p23, p32 = projection[2, 2], projection[2, 3], projection[3, 2]
    # perspective: z_ndc = (p22·z + p23) / (p32·z) at eye-space z; the distance is −z
    dist = np.maximum(p23 / (p22 - p32 * zn), 1e-6)
    lo, hi = float(dist.min()), float(dist.max())
    hi = max(hi, lo * 1.001)
    t = np.log(dist / lo) / math.log(hi / lo)
    out[covered] = ramp(t, DEPTH_RAMP)
    ticks = []
    for v in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000):
        if lo <= v <= hi:
            ticks.append((math.log(v / lo) / math.log(hi / lo), f"{v}"))
    ticks = [(0.0, f"{lo:.1f}")] + [tk for tk in ticks if 0.12 < tk[0] < 0.88] + \
        [(1.0, f"{hi:.0f}")]
    colorbar(out, DEPTH_RAMP, ticks, "distance from the eye (m, log scale)")
    return out


def overdraw_picture(overdraw: np.ndarray) -> tuple[np.ndarray, int]:
    """RGB (H, W, 3) uint8 heat map of fragments tested per pixel, linear from 0 to a top
    value (the 99.5th percentile of covered pixels, rounded up; higher values saturate),
    with a colour bar. Returns (image, top)."""
    o = np.asarray(overdraw, np.int64)
    pos = o[o > 0]
    top = int(np.ceil(np.percentile(pos, 99.5))) if pos.size else 1
    step = max(1, int(nice_step(top, 5)))
    top = max(step, int(math.ceil(top / step) * step))
    img = ramp(o / top, HEAT)
    ticks = [(v / top, str(v)) for v in range(0, top + 1, step)]
    ticks[-1] = (1.0, f"{top}+")
    colorbar(img, HEAT, ticks, "fragments tested per pixel")
    return img, top


def _grow(mask: np.ndarray) -> np.ndarray:
    """`mask` dilated by one pixel (4-neighbourhood)."""
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    return out


def inspector_plane(floor_y: float, cut: float = INSPECTOR_CUT) -> np.ndarray:
    """(1, 4) float64 clip plane (a, b, c, d) = (0, −1, 0, floor_y + cut) for
    ``render(..., clip_planes=...)``: keeps the world points with y <= floor_y + cut, a
    cut-away of everything above one storey's lower ``cut`` metres."""
    return np.array([[0.0, -1.0, 0.0, float(floor_y) + float(cut)]])


def cut_instances(scene: Scene, plane: np.ndarray, world: Mesh | None = None
                  ) -> tuple[int, int]:
    """(instances cut open, instances wholly removed) by a horizontal clip ``plane`` from
    `inspector_plane`: those with faces on both sides of it, and those whose faces all lie
    above it, from their world-space faces (``world``: `world_mesh` of `scene`, made here
    if not given). Instances without faces count in neither."""
    if world is None:
        world = world_mesh(scene)
    y = np.asarray(world.vertices, np.float64)[np.asarray(world.faces), 1]   # (F, 3)
    n = scene.n_instances
    inst = np.repeat(np.arange(n), np.diff(np.append(scene.face_base, scene.n_faces)))
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    np.minimum.at(lo, inst, y.min(axis=1))
    np.maximum.at(hi, inst, y.max(axis=1))
    cut = float(plane[0, 3])
    return int(np.count_nonzero((lo <= cut) & (hi > cut))), int(np.count_nonzero(lo > cut))


def inspector_camera(scene: Scene, floor_y: float, width: int, height: int,
                     cut: float = INSPECTOR_CUT) -> Camera:
    """Third-person camera above, behind (−x) and beside (+z) the storey whose floor is
    at ``floor_y``, framing it (`Camera.framing`) up to ``floor_y + cut``."""
    lo, hi = (np.asarray(a, np.float64) for a in scene.bounds())
    box_lo = np.array([lo[0], floor_y - 0.3, lo[2]])
    box_hi = np.array([hi[0], floor_y + cut, hi[2]])
    return Camera.framing(box_lo, box_hi, direction=(-0.35, 1.0, 0.95), fov_y=40.0,
                          aspect=width / height)


def inspector_picture(frame, fates, world: Mesh, scene: Scene, view_proj: np.ndarray,
                      fp_view_proj: np.ndarray, width: int, height: int, context=None,
                      note: str | None = None) -> tuple[np.ndarray, dict[Fate, int]]:
    """Colour the third-person `frame` of `scene` (rendered cut by `inspector_plane`) by
    the fate of each pixel's cluster in `fates`, shade it lightly (|n·l| of `world`'s
    faces, see `world_mesh`), draw the first-person frustum (``fp_view_proj``) seen through
    ``view_proj`` — depth-tested in `FRUSTUM_COLOR` over its hidden parts in
    `FRUSTUM_HIDDEN_COLOR` — and the legend, with ``note`` (e.g. where the clip plane cuts)
    as its last line where the legend then still fits in the top half of the image (on
    small images it would hide the picture). Returns (image, pixels per fate)."""
    from .output.shade import DEFAULT_LIGHT_DIR
    from .pipeline.lines import LineRenderer, frustum_segments, overlay

    all_inst, face = scene.split_ids(frame.triangle_id)
    hit = all_inst >= 0
    inst = all_inst[hit]
    fate = fates.face_fate(inst, face[hit])
    light = np.asarray(DEFAULT_LIGHT_DIR, np.float64)
    light /= np.linalg.norm(light)
    ids = np.asarray(scene.face_base, np.int64)[inst] + face[hit]
    lam = np.abs(world.face_normals()[ids].astype(np.float64) @ light)
    palette = np.array([FATE_COLORS[f] for f in Fate], np.float64)
    img = np.empty((height, width, 3), np.uint8)
    img[:] = INSPECTOR_BACKGROUND
    img[hit] = np.clip(palette[fate] * (0.45 + 0.55 * lam)[:, None], 0, 255).astype(np.uint8)
    per_fate = {f: int((fate == f).sum()) for f in Fate}

    segs = frustum_segments(fp_view_proj)
    lr = LineRenderer(width, height, context=context)
    s = ui_scale(width, height)
    # LineFrames, or stand-ins with grown masks (what overlay reads: mask, line_id)
    hidden: Any = lr.render(segs, view_proj)
    shown: Any = lr.render(segs, view_proj, depth=frame.depth, depth_bias=1e-4)
    if s > 1:  # thicker lines on big images: grow the masks by one pixel
        hidden, shown = (SimpleNamespace(mask=_grow(f.mask), line_id=f.line_id)
                         for f in (hidden, shown))
    img = overlay(img, hidden, FRUSTUM_HIDDEN_COLOR)
    img = overlay(img, shown, FRUSTUM_COLOR)

    counts = fates.counts()
    rows = [(FATE_COLORS[f], f"{FATE_LABELS[f]}: {counts[f]:,}") for f in Fate]
    rows.append((FRUSTUM_COLOR, "first-person frustum (dim: hidden)"))
    line_h = (TEXT_HEIGHT + 5) * s
    box = 9 * s
    pad = 6 * s
    panel_w = pad * 3 + box + max(text_width(t, s) for _, t in rows)
    title = "culling inspector: clusters by fate in the first-person view"
    if note and pad * 2 + line_h * (len(rows) + 2) > height // 2:
        note = None
    texts = [title] + ([note] if note else [])
    panel(img, 0, 0, max(panel_w, max(text_width(t, s) for t in texts) + 2 * pad),
          pad * 2 + line_h * (len(rows) + len(texts)))
    draw_text(img, pad, pad, title, (240, 240, 240), s)
    for k, (col, txt) in enumerate(rows):
        y = pad + line_h * (k + 1)
        img[y:y + box - s, pad:pad + box] = col
        draw_text(img, pad * 2 + box, y, txt, (230, 230, 230), s)
    if note:
        draw_text(img, pad, pad + line_h * (len(rows) + 1), note, (200, 200, 200), s)
    return img, per_fate


# -- command line ----------------------------------------------------------------------

def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="clraster demo",
        description="Render the built-in procedural power plant from a first-person "
                    "corridor camera with frustum, normal-cone and occlusion culling, and "
                    "write shaded.png, depth.png, overdraw.png and inspector.png (a "
                    "third-person view with every cluster coloured by its fate).")
    p.add_argument("--out", type=Path, default=Path("demo"), metavar="DIR",
                   help="folder for the images, created if missing (default demo/)")
    p.add_argument("--size", type=parse_size, default=(1280, 720), metavar="WxH",
                   help="image size in pixels (default 1280x720)")
    p.add_argument("--triangles", type=_triangles, default=1_000_000, metavar="N",
                   help=f"plant size in triangles, 2000..{MAX_TRIANGLES:,} (default "
                        f"1000000); the cap bounds host memory, about 300 bytes per "
                        f"triangle (some 15 GiB at the cap)")
    p.add_argument("--frames", type=parse_positive_int, default=3, metavar="N",
                   help="first-person frames to render, >= 1 (default 3); the images show "
                        "the last one, whose occlusion culling reuses the previous frame's "
                        "visibility")
    p.add_argument("--no-occlusion", action="store_true",
                   help="frustum and cone culling only")
    return p


def _triangles(text: str) -> int:
    try:
        v = int(text.replace("_", "").replace(",", ""))
    except ValueError:
        v = -1
    if v < 2000:
        raise argparse.ArgumentTypeError(f"expected a whole number of triangles >= 2000, "
                                         f"got {text!r}")
    if v > MAX_TRIANGLES:
        raise argparse.ArgumentTypeError(
            f"at most {MAX_TRIANGLES:,} triangles (the demo needs about 300 bytes of host "
            f"memory per triangle, some 15 GiB at the cap), got {text!r}")
    return v


def _run(args: argparse.Namespace) -> int:
    import imageio.v3 as iio

    from .cmdline import check_output_folder
    from .output.lights import Light
    from .output.post import SSAO
    from .output.shade import render_shaded
    from .pipeline.renderer import Renderer
    from .world.generators import EYE_HEIGHT, plant, plant_inside_camera

    # before the plant is built and rendered (minutes at a million triangles), not after
    check_output_folder(args.out, "--out", parents=True)
    w, h = args.size
    occlusion = not args.no_occlusion
    t0 = time.perf_counter()
    scene = plant(args.triangles)
    t_scene = (time.perf_counter() - t0) * 1e3
    print(f"scene: plant({args.triangles:,}): {scene.n_instances:,} instances, "
          f"{scene.n_faces:,} triangles ({t_scene:.0f} ms)")
    cam = plant_inside_camera(scene, w, h)
    t0 = time.perf_counter()
    renderer = Renderer(w, h)
    t_init = (time.perf_counter() - t0) * 1e3
    print(f"device: {renderer.context.devices[0].name.strip()} "
          f"(renderer set-up {t_init:.0f} ms)")
    times = []
    frame = None
    for _ in range(args.frames):
        t0 = time.perf_counter()
        frame = renderer.render(scene, cam, occlusion=occlusion, overdraw=True, fates=True)
        times.append((time.perf_counter() - t0) * 1e3)
        if occlusion:
            st = frame.stats
            print(f"frame {len(times)}: {times[-1]:7.1f} ms  phase 1 drew "
                  f"{st.clusters_phase1:,} clusters, phase 2 {st.clusters_phase2:,}, "
                  f"occlusion culled {st.clusters_occlusion_culled:,}")
        else:
            print(f"frame {len(times)}: {times[-1]:7.1f} ms")
    assert frame is not None and frame.fates is not None
    print(f"\nculling funnel (frame {len(times)}, {w}x{h}):")
    print(frame.stats)
    line = f"frame time: first {times[0]:.1f} ms (includes kernel build"
    line += ", no visibility history)" if occlusion else ")"
    if len(times) > 1:
        warm = times[1:]
        line += f"; warm: best {min(warm):.1f} ms, last {warm[-1]:.1f} ms"
        if occlusion:
            line += " (occlusion reuses the previous frame's visible set)"
    print(line)
    counts = frame.fates.counts()
    print("cluster fates: " + ", ".join(f"{FATE_LABELS[f]} {counts[f]:,}" for f in Fate)
          + f" (of {len(frame.fates):,})")

    t0 = time.perf_counter()
    world = world_mesh(scene)
    t1 = time.perf_counter()
    lights = [Light.directional(SUN_DIRECTION),
              Light.spot(np.asarray(cam.eye, float) + LAMP_OFFSET, LAMP_DIRECTION,
                         cone=LAMP_CONE, shadow_size=1024)]
    shaded = render_shaded(renderer, scene, cam, lights=lights, shadows=True,
                           ssao=SSAO(radius=AO_RADIUS), render_kwargs={"occlusion": occlusion})
    t_shaded = (time.perf_counter() - t1) * 1e3
    depth = depth_picture(frame, cam.projection(w, h))
    over, top = overdraw_picture(cast(np.ndarray, frame.overdraw))   # overdraw=True
    floor_y = float(cam.eye[1]) - EYE_HEIGHT
    plane = inspector_plane(floor_y)
    crossing, above = cut_instances(scene, plane, world)
    icam = inspector_camera(scene, floor_y, w, h)
    # the whole plant, cut by the plane: what crosses it is cut open, not left out
    iframe = renderer.render(scene, icam, clip_planes=plane)
    inspector, per_fate = inspector_picture(
        iframe, frame.fates, world, scene, icam.view_projection(w, h),
        cam.view_projection(w, h), w, h, context=renderer.context,
        note=f"clip plane: everything above {INSPECTOR_CUT:g} m over the floor cut away")
    t_img = (time.perf_counter() - t0) * 1e3
    args.out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, img in (("shaded.png", shaded), ("depth.png", depth),
                      ("overdraw.png", over), ("inspector.png", inspector)):
        path = args.out / name
        iio.imwrite(path, img)
        written.append(path)
    o = cast(np.ndarray, frame.overdraw)
    print(f"overdraw: mean {o[o > 0].mean():.2f} fragments per covered pixel, max "
          f"{int(o.max())}; heat scale 0..{top} (black = none, white = {top} or more)")
    print(f"inspector: clip plane y <= {float(plane[0, 3]):.2f} ({INSPECTOR_CUT:g} m over the "
          f"floor): {above:,} of {scene.n_instances:,} instances wholly above it, "
          f"{crossing:,} cut open; pixels " + ", ".join(
              f"{FATE_LABELS[f].split(' (')[0]} {per_fate[f]:,}" for f in Fate))
    print(f"images: {t_img:.0f} ms (shaded.png with its lights' shadow maps and ambient "
          f"occlusion: {t_shaded:.0f} ms)")
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``clraster demo`` with `argv` (default ``sys.argv[1:]``); returns the exit code."""
    parser = _parser()
    try:
        args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return int(exc.code or 0)
    from .cmdline import run_guarded

    return run_guarded("clraster demo", lambda: _run(args))


if __name__ == "__main__":
    sys.exit(main())
