"""clraster's shadow maps next to pyrender's, on one scene: docs/shadows_vs_pyrender.png.

One scene both tools draw — a 12 × 12 floor quad, a cube, a thin tall slab (a thin
occluder), a box floating 0.3 above the floor (its shadow must detach from it), a sphere
(icosphere, 1,280 faces) and Keenan Crane's spot (/work/shared/meshes/spot.ply, 5,856
faces) — concatenated into *one* trimesh with face colours, so both tools get the same
triangles. The same camera: a pyrender ``PerspectiveCamera`` and its pose, turned into
clraster's with ``Camera.from_pyrender(camera, pose, W, H)``. The same directional light:
pyrender's ``DirectionalLight`` on a node whose −Z axis is ``LIGHT_DIR`` (pyrender's
convention), ``render(scene, flags=RenderFlags.SHADOWS_DIRECTIONAL)``; clraster's
``Light.directional(LIGHT_DIR)`` through ``render_shaded(..., shadows=True,
return_layers=True)``.

What is compared, on the floor pixels both tools see (clraster's triangle id is one of the
floor's two faces, and pyrender's linear depth agrees with clraster's within 0.1%):

* clraster: the lit fraction ``layers.lit[..., 0]`` (shadow-map visibility after PCF).
* pyrender: its shader multiplies the light's term by ``1 − shadow`` and, with no ambient
  light and no other light, that is the only term; the output is ``clamp(c^(1/2.2))``. So
  two extra renders with ``ambient_light = 0`` — with and without SHADOWS_DIRECTIONAL — give
  pyrender's own lit fraction per pixel as ``(I_shadows / I_plain)^2.2`` (I the sum of the
  8-bit RGB; the light is dimmed so nothing clamps). That is the image brightness,
  normalized by the unshadowed brightness of the same pixel (which removes the view-
  dependent specular and the colour), thresholded at 0.5 like clraster's lit fraction.
* a float64 shadow-ray oracle: the floor point of each pixel (the pixel-centre ray meets
  the plane y = 0, analytically) casts a ray towards the light against every other
  triangle (Möller–Trumbore in float64, after a per-object bounding-box test).

Set up (pyrender 0.1.45 uses ``np.infty``, which NumPy 2 removed, so it gets its own venv
with NumPy 1.x; the renders go through Mesa's EGL + llvmpipe, headless)::

    python3 -m venv /tmp/pyr
    echo "numpy<2" > /tmp/pyr-constraints.txt
    /tmp/pyr/bin/pip install -c /tmp/pyr-constraints.txt pyrender -e .
    PYOPENGL_PLATFORM=egl EGL_PLATFORM=surfaceless /tmp/pyr/bin/python \
        bench/shadows_vs_pyrender.py            # writes docs/shadows_vs_pyrender.png

(the two variables are set by the script when unset). It prints the agreement numbers that
docs/OTHER_TOOLS.md quotes. Without pyrender it exits with a message saying so.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

# headless: PyOpenGL reads its platform when first imported (pyrender imports it)
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("EGL_PLATFORM", "surfaceless")
ROOT = Path(__file__).resolve().parents[1]
SPOT = Path("/work/shared/meshes/spot.ply")
#: The direction the light travels (clraster's Light.directional; pyrender's node −Z).
LIGHT_DIR = np.array([0.55, -1.0, -0.45])
EYE = np.array([5.0, 4.2, 7.5])
LOOK_AT = np.array([0.0, 0.4, 0.0])
YFOV = np.radians(40.0)
NEAR, FAR = 0.1, 60.0
FLOOR_FACES = 2  # the floor is faces 0 and 1 of the concatenated mesh


def _colored(mesh, rgb):
    mesh.visual.face_colors = np.array([*rgb, 255], np.uint8)
    return mesh


def build_scene():
    """One trimesh.Trimesh (floor first) with face colours, and [(name, first, last face)]."""
    import trimesh

    parts = []
    floor = trimesh.Trimesh(vertices=[[-6, 0, -6], [-6, 0, 6], [6, 0, 6], [6, 0, -6]],
                            faces=[[0, 1, 2], [0, 2, 3]], process=False)
    parts.append(("floor", _colored(floor, (215, 215, 210))))
    cube = trimesh.creation.box((1.0, 1.0, 1.0))
    cube.apply_translation((-1.8, 0.5, 0.6))
    parts.append(("cube", _colored(cube, (200, 90, 70))))
    slab = trimesh.creation.box((0.08, 2.2, 1.6))   # thin occluder
    slab.apply_translation((0.9, 1.1, -1.6))
    parts.append(("slab", _colored(slab, (90, 140, 200))))
    floating = trimesh.creation.box((0.9, 0.35, 0.9))   # bottom at y = 0.3
    floating.apply_translation((2.4, 0.475, 1.2))
    parts.append(("floating box", _colored(floating, (110, 180, 100))))
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    sphere.apply_translation((-1.2, 0.7, -2.0))
    parts.append(("sphere", _colored(sphere, (220, 180, 80))))
    spot = trimesh.load(SPOT, process=False)
    spot.apply_translation((0.6, -spot.bounds[0, 1], 2.0))
    parts.append(("spot", _colored(spot, (190, 150, 200))))
    mesh = trimesh.util.concatenate([p for _, p in parts])
    ranges, start = [], 0
    for name, p in parts:
        ranges.append((name, start, start + len(p.faces)))
        start += len(p.faces)
    assert ranges[0] == ("floor", 0, FLOOR_FACES)
    return mesh, ranges


def _look_at_pose(eye, target, up=(0.0, 1.0, 0.0)):
    """Camera → world, OpenGL axes: the camera looks down its −Z at `target`."""
    z = eye - target
    z = z / np.linalg.norm(z)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, np.cross(z, x), z, eye
    return pose


def _light_pose():
    """A node whose −Z axis is LIGHT_DIR (pyrender's directional light shines along it)."""
    d = LIGHT_DIR / np.linalg.norm(LIGHT_DIR)
    return _look_at_pose(np.zeros(3), d, up=(0.0, 0.0, 1.0))


def render_pyrender(mesh, width, height):
    """(picture, lit fraction, linear depth) from pyrender; lit as the module docstring says."""
    import pyrender

    cam = pyrender.PerspectiveCamera(yfov=YFOV, znear=NEAR, zfar=FAR,
                                     aspectRatio=width / height)
    cam_pose = _look_at_pose(EYE, LOOK_AT)
    material = pyrender.MetallicRoughnessMaterial(baseColorFactor=(1.0, 1.0, 1.0, 1.0),
                                                  metallicFactor=0.0, roughnessFactor=1.0)
    # one primitive, flat: three vertices per face with the face's normal and colour (as
    # floats: from_trimesh passes trimesh's uint8 colours on unscaled, which saturates them)
    n = len(mesh.faces)
    prim = pyrender.Primitive(
        positions=np.asarray(mesh.vertices, np.float32)[mesh.faces].reshape(-1, 3),
        normals=np.repeat(np.asarray(mesh.face_normals, np.float32), 3, axis=0),
        color_0=np.repeat(mesh.visual.face_colors[:, :3] / 255.0, 3, axis=0).astype(np.float32),
        indices=np.arange(3 * n, dtype=np.uint32).reshape(n, 3), material=material)
    pmesh = pyrender.Mesh([prim])
    r = pyrender.OffscreenRenderer(width, height)
    flags = pyrender.RenderFlags.SHADOWS_DIRECTIONAL

    def scene(ambient, intensity):
        s = pyrender.Scene(ambient_light=np.full(3, ambient), bg_color=(1.0, 1.0, 1.0))
        s.add(pmesh)
        s.add(cam, pose=cam_pose)
        s.add(pyrender.DirectionalLight(intensity=intensity), pose=_light_pose())
        return s

    try:
        shown = scene(0.25, 3.0)
        # pyrender's directional shadow camera: orthographic, xmag = ymag = the scene's
        # diagonal (light.py), on SHADOW_TEX_SZ² texels
        texel = 2.0 * shown.scale / pyrender.constants.SHADOW_TEX_SZ
        picture, depth = r.render(shown, flags=flags)
        dim = scene(0.0, 1.5)
        shadowed, _ = r.render(dim, flags=flags)
        plain, _ = r.render(dim)
    finally:
        r.delete()
    if plain[depth > 0].max() >= 255:
        raise RuntimeError("the unshadowed measuring render clamps; lower its intensity")
    i_s = shadowed.astype(np.float64).sum(axis=2)
    i_p = plain.astype(np.float64).sum(axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        lit = np.where(i_p > 0, np.clip(i_s / i_p, 0.0, 1.0) ** 2.2, np.nan)
    return picture, lit, depth, cam, cam_pose, texel


def render_clraster(mesh, cam):
    """(picture, lit fraction, triangle ids, linear depth, shadow texel) from clraster."""
    from clraster.shade import Light, render_shaded

    import clraster

    r = clraster.Renderer(cam.width, cam.height)
    picture, layers = render_shaded(r, mesh, cam.camera, lights=[Light.directional(LIGHT_DIR)],
                                    shadows=True, return_layers=True)
    frame = r.render(mesh, cam.camera)
    return (picture, layers.lit[..., 0], frame.triangle_id, frame.linear_depth(cam.camera),
            layers.shadow_maps[0].texel)


class _Cam:
    def __init__(self, pyr_cam, pose, width, height):
        import clraster

        self.camera = clraster.Camera.from_pyrender(pyr_cam, pose, width, height)
        self.width, self.height = width, height


def floor_points(cam, width, height):
    """float64 (H, W, 3) point of y = 0 under each pixel centre (nan where the ray misses)."""
    inv = np.linalg.inv(np.asarray(cam.view_projection(width, height), np.float64))
    xs = (np.arange(width) + 0.5) / width * 2.0 - 1.0
    ys = 1.0 - (np.arange(height) + 0.5) / height * 2.0
    nx, ny = np.meshgrid(xs, ys)
    def unproject(z):
        p = np.stack([nx, ny, np.full_like(nx, z), np.ones_like(nx)], -1) @ inv.T
        return p[..., :3] / p[..., 3:]
    a, b = unproject(-1.0), unproject(1.0)
    t = a[..., 1] / (a[..., 1] - b[..., 1])
    pts = a + t[..., None] * (b - a)
    pts[~((t > 0) & np.isfinite(t))] = np.nan
    return pts


def oracle_lit(points, mesh, ranges):
    """bool (K,): the ray from each float64 point towards the light hits no occluder face."""
    to_light = -LIGHT_DIR / np.linalg.norm(LIGHT_DIR)
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces)
    blocked = np.zeros(len(points), bool)
    for _, lo, hi in ranges[1:]:
        tri = v[f[lo:hi]]
        bmin, bmax = tri.reshape(-1, 3).min(0) - 1e-9, tri.reshape(-1, 3).max(0) + 1e-9
        with np.errstate(divide="ignore", invalid="ignore"):   # slab test first
            t0, t1 = (bmin - points) / to_light, (bmax - points) / to_light
        near = np.minimum(t0, t1).max(1)
        far = np.maximum(t0, t1).min(1)
        cand = np.flatnonzero((far >= np.maximum(near, 0.0)) & ~blocked)
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        pvec = np.cross(to_light, e2)
        det = (e1 * pvec).sum(1)
        ok = np.abs(det) > 1e-15
        e1, e2, t0v, pvec, det = e1[ok], e2[ok], tri[ok, 0], pvec[ok], det[ok]
        for s in range(0, len(cand), 512):
            idx = cand[s:s + 512]
            tv = points[idx, None, :] - t0v[None]
            u = (tv * pvec).sum(2) / det
            q = np.cross(tv, e1[None])
            w = (q * to_light).sum(2) / det
            t = (q * e2[None]).sum(2) / det
            hit = (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 1e-9)
            blocked[idx] |= hit.any(1)
    return ~blocked


def _band(mask, radius):
    """Pixels within `radius` (Chebyshev) of a pixel whose value differs: boundary band."""
    grow, shrink = mask.copy(), mask.copy()
    pad = np.pad(mask, radius, mode="edge")
    h, w = mask.shape
    for dy in range(2 * radius + 1):
        for dx in range(2 * radius + 1):
            win = pad[dy:dy + h, dx:dx + w]
            grow |= win
            shrink &= win
    return grow & ~shrink


def compare(cl_lit, pr_lit, ids, cl_depth, pr_depth, mesh, ranges, cam, width, height):
    """The agreement numbers, and a (H, W) code map: 0 none, 1 both lit, 2 both shadowed,
    3 clraster shadowed only, 4 pyrender shadowed only."""
    pts = floor_points(cam, width, height)
    # the floor's exact depth along the view axis: both tools' depth buffers lose precision
    # far away (clraster's float32 window depth, pyrender's 24-bit one)
    view = np.asarray(cam.view, np.float64)
    exact = -(pts @ view[:3, :3].T + view[:3, 3])[..., 2]
    floor = (ids >= 0) & (ids < FLOOR_FACES) & (pr_depth > 0) & np.isfinite(pr_lit)
    floor &= np.abs(pr_depth - exact) <= 0.01 * exact
    cl = cl_lit >= 0.5
    pr = pr_lit >= 0.5
    ora = np.zeros_like(floor)
    ora[floor] = oracle_lit(pts[floor], mesh, ranges)
    # pixels farther than 2 px from an oracle shadow boundary (as issue 35's check does)
    interior = floor & ~_band(np.where(floor, ora, True), 2)
    n = int(floor.sum())
    out = {
        "floor pixels": n,
        "both lit": float((cl & pr)[floor].mean()),
        "both shadowed": float((~cl & ~pr)[floor].mean()),
        "agree": float((cl == pr)[floor].mean()),
        "clraster shadowed only": float((~cl & pr)[floor].mean()),
        "pyrender shadowed only": float((cl & ~pr)[floor].mean()),
        "shadowed, clraster": float((~cl)[floor].mean()),
        "shadowed, pyrender": float((~pr)[floor].mean()),
        "shadowed, oracle": float((~ora)[floor].mean()),
        "interior pixels": int(interior.sum()),
        "clraster = oracle (interior)": float((cl == ora)[interior].mean()),
        "pyrender = oracle (interior)": float((pr == ora)[interior].mean()),
        "clraster = oracle (all floor)": float((cl == ora)[floor].mean()),
        "pyrender = oracle (all floor)": float((pr == ora)[floor].mean()),
        "oracle-lit interior with lit < 0.9, clraster": float(
            (cl_lit < 0.9)[ora & interior].mean()),
        "oracle-lit interior with lit < 0.9, pyrender": float(
            (pr_lit < 0.9)[ora & interior].mean()),
    }
    code = np.zeros(ids.shape, np.uint8)
    code[floor & cl & pr] = 1
    code[floor & ~cl & ~pr] = 2
    code[floor & ~cl & pr] = 3
    code[floor & cl & ~pr] = 4
    return out, code


def figure(cl_img, pr_img, code, stats, path):
    """2 × 2 panels: clraster | pyrender, agreement map | numbers; labelled."""
    from PIL import Image, ImageDraw, ImageFont

    h, w = code.shape
    colours = np.array([[255, 255, 255], [235, 235, 235], [120, 120, 120],
                        [220, 40, 40], [40, 90, 230]], np.uint8)
    amap = colours[code]
    geom = code == 0
    amap[geom] = (0.35 * cl_img[geom] + 0.65 * 255).astype(np.uint8)  # objects faded
    bar = 34
    canvas = Image.new("RGB", (2 * w, 2 * (h + bar)), "white")
    font = ImageFont.load_default(size=22)
    small = ImageFont.load_default(size=19)
    draw = ImageDraw.Draw(canvas)
    panels = [(cl_img, "clraster render_shaded(shadows=True)"),
              (pr_img, "pyrender 0.1.45, SHADOWS_DIRECTIONAL (llvmpipe)"),
              (amap, "floor: lit / shadowed in both; red: clraster only; blue: pyrender only")]
    for k, (img, label) in enumerate(panels):
        x, y = (k % 2) * w, (k // 2) * (h + bar)
        canvas.paste(Image.fromarray(np.ascontiguousarray(img[..., :3])), (x, y + bar))
        draw.text((x + 8, y + 6), label, fill="black", font=font if k < 2 else small)
    lines = [f"{stats['floor pixels']:,} floor pixels both tools see, lit = fraction >= 0.5",
             f"agree: {100 * stats['agree']:.2f}%  (both lit {100 * stats['both lit']:.1f}%,"
             f" both shadowed {100 * stats['both shadowed']:.1f}%)",
             f"shadowed by clraster only: {100 * stats['clraster shadowed only']:.2f}%",
             f"shadowed by pyrender only: {100 * stats['pyrender shadowed only']:.2f}%",
             "against a float64 shadow-ray oracle, pixels > 2 px",
             "from its shadow boundaries:",
             f"  clraster {100 * stats['clraster = oracle (interior)']:.3f}%,"
             f" pyrender {100 * stats['pyrender = oracle (interior)']:.3f}%",
             "lit floor (oracle) darkened below 0.9 by its own shadow (acne):",
             f"  clraster {100 * stats['oracle-lit interior with lit < 0.9, clraster']:.2f}%,"
             f" pyrender {100 * stats['oracle-lit interior with lit < 0.9, pyrender']:.1f}%",
             "same mesh, camera (Camera.from_pyrender) and light;",
             "pyrender: PBR + gamma 2.2, ambient 0.25;",
             "clraster: Lambert, ambient 0.22, no gamma"]
    x0, y0 = w + 20, h + bar + 20
    for i, line in enumerate(lines):
        draw.text((x0, y0 + 32 * i), line, fill="black", font=small)
    canvas.save(path, optimize=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--height", type=int, default=600)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "shadows_vs_pyrender.png")
    args = ap.parse_args(argv)
    try:
        import pyrender  # noqa: F401
    except Exception as exc:   # ImportError, or an OpenGL platform that cannot load
        sys.exit(f"pyrender cannot be imported here ({exc!r}); see this script's docstring "
                 f"for the venv it needs")
    mesh, ranges = build_scene()
    w, h = args.width, args.height
    pr_img, pr_lit, pr_depth, pyr_cam, pose, pr_texel = render_pyrender(mesh, w, h)
    cam = _Cam(pyr_cam, pose, w, h)
    cl_img, cl_lit, ids, cl_depth, cl_texel = render_clraster(mesh, cam)
    stats, code = compare(cl_lit, pr_lit, ids, cl_depth, pr_depth, mesh, ranges, cam.camera,
                          w, h)
    stats["shadow texel (world units), clraster"] = float(cl_texel)
    stats["shadow texel (world units), pyrender"] = float(pr_texel)
    for k, v in stats.items():
        print(f"{k:45s} {v:.5f}" if isinstance(v, float) else f"{k:45s} {v}")
    figure(cl_img, pr_img, code, stats, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
