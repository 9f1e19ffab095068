"""What a frame gives beyond its buffers — metric depth, distance, normals, point clouds —
and the files they are written to.

The command line, `Frame.save` and the batch paths (`clraster.scale.batch`,
`clraster.scale.distributed`) call one function::

    write_output(path, frame, what, *, target=None, camera=None, depth_scale=None,
                 smooth=None, space=None, **shade_options) -> Path

A frame rendered with these outputs asked for (``render(..., outputs=("linear_depth",
"normals", ...))``) carries them made on the device (`clraster.Frame.resolved`, by the
resolve stage: `clraster.pipeline.resolving`), and every function here returns those
arrays (`resolved_output`); otherwise they are computed on the host, in NumPy, from the
frame's buffers (ids, barycentrics, window depth) and the target's geometry.

``what`` (`OUTPUTS`) and what it needs:

============== ============ =====================================================================
what           needs        meaning
============== ============ =====================================================================
"depth"        —            window depth (z/w + 1)/2 in [0, 1], 1.0 on the background
                            (reversed-Z frames: (1 − z/w)/2, 0.0 on the background)
"linear_depth" camera       eye-space depth along the view axis, scene units, inf on the background
"distance"     camera       distance from the eye along the pixel's ray, scene units, inf background
"ids"          —            triangle ids, int32, −1 on the background
"bary"         —            (H, W, 3) float32 barycentrics (`Frame.barycentrics`)
"mask"         —            bool, True where a triangle covers the pixel (``ids >= 0``)
"normals"      target       unit world-space face normals (``smooth=True``: interpolated vertex
                            normals; ``space="camera"`` with a camera), zeros on the background
"shaded"       target       `clraster.shade.shade(frame, target, **shade_options)`, uint8 RGB(A)
"points"       target       the covered pixels' positions (`Frame.points`) with their normals
                            (as "normals": ``smooth``, ``space``); ``space="camera"``: both in
                            OpenGL eye space (x right, y up, z towards the viewer)
============== ============ =====================================================================

With a ``target`` (the Mesh / Scene / trimesh object the frame was rendered from),
"linear_depth" and "distance" come from the exact surface points (ids + barycentrics, float64)
instead of the float32 window depth, whose metric error grows with the square of the distance.

Options an output does not use are refused (ValueError naming them), never ignored:
``target`` is read by linear_depth, distance, normals, shaded, points; ``camera`` by
linear_depth, distance, and normals / points with ``space="camera"``; ``depth_scale`` by
linear_depth / distance written as .png only; ``smooth`` by normals, shaded, points;
``space`` by normals, points; shade options by shaded.

The file's extension picks the format, and the file written is exactly the file named (no
extension is appended); an unknown extension or a format that cannot hold the data is refused
before anything is computed or written. Files are written to a temporary name in the same
folder and renamed, so a reader never sees half a file.

* ``.png`` — what RGB-D datasets store. "linear_depth"/"distance": uint16 ``round(value ·
  depth_scale)``, ``depth_scale`` in PNG units per scene unit (default 1000: millimetres for a
  scene in metres; TUM uses 5000), 0 = no depth; a value that does not fit 1..65535 is
  refused, never wrapped or clamped (choose a smaller scale, or .tiff / .npy).
  "depth": uint16 ``round(d · 65535)`` (OpenGL's 16-bit unsigned-normalized depth; background
  65535). "ids": uint16 ``id + 1`` (0 = background), only if every id fits, else refused.
  "normals": RGB8 ``round((n + 1)/2 · 255)``, background 0. "mask": uint8 255 covered, 0 not.
  "shaded": RGB(A)8.
* ``.tif`` / ``.tiff`` — float32 depth (window, linear, distance; inf on the background for
  the metric ones), int32 ids, uint8 mask (255 / 0), float32 (H, W, 3) normals and
  barycentrics, uint8 shaded. Written by imageio's tifffile plugin where the `tifffile`
  package is installed; without it 2-D float32/int32 and uint8 images go through Pillow, and
  (H, W, 3) float32 images are refused with a message naming tifffile (`check_writable`).
* ``.exr`` — float32, only where an imageio plugin writes EXR (else a clear error).
* ``.npy`` — the array itself (mask: bool; points: (N, 6) float64, columns x y z nx ny nz).
  ``.npz`` — named arrays: ``{what: array}``; points: ``points`` (N, 3) float64,
  ``normals`` (N, 3) float32, ``ids`` (N,) int32, ``pixels`` (N, 2) int32 (x, y).
* ``.ply`` — "points" only: a binary little-endian point cloud, one ``vertex`` element with
  float32 properties ``x y z nx ny nz``.
"""

from __future__ import annotations

import io
import os
import warnings
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np

from ..world.inputs import as_target
from ..world.mesh import Mesh
from ..world.scene import Scene
from .atomic import write_atomic
from .shade import pixel_normals, shade
from .surface import affine_rows, blend_rows, dot_rows, mat3_rows, unit_rows

__all__ = ["FORMATS", "OUTPUTS", "FrameBuffers", "FramePoints", "camera_axes",
           "check_output_options", "check_output_path", "check_writable", "distance",
           "linear_depth", "normals", "point_normals", "points", "resolved_output",
           "write_output"]

#: What `write_output` can write.
OUTPUTS = ("depth", "linear_depth", "distance", "ids", "normals", "shaded", "points", "bary",
           "mask")
_IMAGES = ("depth", "linear_depth", "distance", "ids", "normals", "shaded", "mask")
#: Extensions (lower case) and the outputs each can hold.
FORMATS: dict[str, tuple[str, ...]] = {
    ".png": _IMAGES,
    ".tif": _IMAGES + ("bary",),
    ".tiff": _IMAGES + ("bary",),
    ".exr": ("depth", "linear_depth", "distance", "normals", "bary"),
    ".npy": OUTPUTS,
    ".npz": OUTPUTS,
    ".ply": ("points",),
}
_NEEDS_CAMERA = ("linear_depth", "distance")
_NEEDS_TARGET = ("normals", "shaded", "points")
#: option → the outputs that read it (``camera`` also by normals / points in camera space,
#: ``depth_scale`` only in a .png: `check_output_options`)
_READ_BY = {"target": ("linear_depth", "distance", "normals", "shaded", "points"),
            "camera": ("linear_depth", "distance"),
            "depth_scale": ("linear_depth", "distance"),
            "smooth": ("normals", "shaded", "points"),
            "space": ("normals", "points")}
_U16_MAX = 65535


class FrameBuffers(Protocol):
    """What the outputs read of a frame: a `clraster.Frame` (whose `Frame.save`,
    `Frame.points`... call this module), or anything with its buffers and depth convention."""

    @property
    def depth(self) -> np.ndarray: ...

    @property
    def triangle_id(self) -> np.ndarray: ...

    @property
    def reversed_z(self) -> bool: ...

    def need_barycentrics(self) -> np.ndarray: ...


class FramePoints(NamedTuple):
    """A frame's covered pixels as a point cloud, in row-major pixel order.

    Attributes:
        points: (N, 3) float64 world positions of the visible surface at the pixel centres.
        ids: (N,) int32 triangle ids (as in ``frame.triangle_id``).
        pixels: (N, 2) int32 pixel coordinates (x, y), row 0 at the top.
    """

    points: np.ndarray
    ids: np.ndarray
    pixels: np.ndarray


# -- geometry of the visible surface --------------------------------------------------------

def resolved_output(frame: Any, name: str, camera: Any = None) -> np.ndarray | None:
    """The output ``name`` the device made for ``frame`` (`clraster.Frame.resolved`), or
    None when the frame has none: it was not asked for, or ``camera`` (given for the
    outputs that depend on it: metric depths, camera-space normals) is not the camera it
    was made with (its ``view`` and ``projection`` differ from `Frame.resolved_camera`)."""
    got = getattr(frame, "resolved", None)
    if not got or name not in got:
        return None
    if camera is not None:
        made = getattr(frame, "resolved_camera", None)
        if made is None:
            return None
        h, w = np.shape(frame.triangle_id)
        try:
            view = np.asarray(camera.view, np.float64)
            proj = np.asarray(camera.projection(w, h), np.float64)
        except (AttributeError, TypeError, ValueError):
            return None
        if not (np.array_equal(view, made[0]) and np.array_equal(proj, made[1])):
            return None
    return got[name]


def _as_geometry(target: Any) -> Mesh | Scene:
    """`target` as the Mesh or Scene the renderer drew: trimesh objects through the same
    cached conversion as the renderer (`clraster.inputs.as_target`), so ids match."""
    return as_target(target)


def _covered(frame: FrameBuffers, n_faces: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ys, xs, ids) of the covered pixels, row-major; ids checked against the target."""
    ids = np.asarray(frame.triangle_id)
    ys, xs = np.nonzero(ids >= 0)
    sel = ids[ys, xs]
    if sel.size and int(sel.max()) >= n_faces:
        raise ValueError(f"frame holds triangle id {int(sel.max())} but the target has "
                         f"{n_faces} faces: was the frame rendered from this target?")
    return ys, xs, sel


def points(frame: FrameBuffers, target: Any, space: str = "world",
           camera: Any = None) -> FramePoints:
    """Positions of the covered pixels (see `FramePoints`): each pixel's barycentrics
    (perspective-correct, relative to its face's own three vertices) applied to the face's
    world-space vertices in float64 (a Scene's instance transform applied first).
    ``space="camera"``: those world points mapped by the camera's view matrix into OpenGL eye
    space (x right, y up, z towards the viewer; needs `camera`)."""
    _check_space(space, camera, "points")
    made = resolved_output(frame, "points")
    if made is not None:   # the device's surface points: gathered, row-major
        ids_img = np.asarray(frame.triangle_id)
        ys, xs = np.nonzero(ids_img >= 0)
        world = made[ys, xs]
        pixels = np.stack([xs, ys], axis=1).astype(np.int32)
        if space == "camera":
            h, w = ids_img.shape
            view = _camera_frame(camera, w, h)[0]
            world = world @ view[:3, :3].T + view[:3, 3]
        return FramePoints(world, ids_img[ys, xs].astype(np.int32), pixels)
    geom = _as_geometry(target)
    n_faces = geom.n_faces
    ys, xs, ids = _covered(frame, n_faces)
    bary = np.asarray(frame.need_barycentrics(), np.float64)[ys, xs]   # (N, 3)
    # in the resolve kernel's order (clraster.output.surface): the same bits as the device
    if isinstance(geom, Mesh):
        tri = geom.vertices.astype(np.float64)[geom.faces[ids]]      # (N, 3, 3)
        world = blend_rows(bary, tri[:, 0], tri[:, 1], tri[:, 2])
    else:
        inst, face = geom.split_ids(ids)
        world = np.empty((len(ids), 3))
        for i in np.unique(inst):
            sel = inst == i
            instance = geom.instances[int(i)]
            m = instance.mesh
            tri = m.vertices.astype(np.float64)[m.faces[face[sel]]]
            local = blend_rows(bary[sel], tri[:, 0], tri[:, 1], tri[:, 2])
            world[sel] = affine_rows(np.asarray(instance.transform, np.float64)[:3].reshape(-1),
                                     local)
    pixels = np.stack([xs, ys], axis=1).astype(np.int32)
    if space == "camera":
        h, w = frame.triangle_id.shape
        view = _camera_frame(camera, w, h)[0]
        world = world @ view[:3, :3].T + view[:3, 3]
    return FramePoints(world, ids.astype(np.int32), pixels)


def point_normals(frame: FrameBuffers, target: Any, smooth: bool = False,
                  space: str = "world", camera: Any = None) -> np.ndarray:
    """(N, 3) float32 unit normals of the covered pixels, in the order of `points` (row-major
    pixels): `normals` (same ``smooth``, ``space``, ``camera``) at those pixels."""
    n = normals(frame, target, smooth=smooth, space=space, camera=camera)
    return n[np.asarray(frame.triangle_id) >= 0]


def _check_space(space: str, camera: Any, what: str) -> None:
    if space not in ("world", "camera"):
        raise ValueError(f"space must be 'world' or 'camera', got {space!r}")
    if space == "camera" and camera is None:
        raise ValueError(f"{what} in camera space need the camera: "
                         f"frame.{what}(target, space='camera', camera=camera)")


def _camera_frame(camera: Any, width: int, height: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(view, projection, eye, orthographic) of a clraster.Camera-like object."""
    try:
        view = np.asarray(camera.view, np.float64)
        proj = np.asarray(camera.projection(width, height), np.float64)
    except AttributeError:
        raise ValueError(f"metric depth needs the camera the frame was rendered with (a "
                         f"clraster.Camera, with view and projection), got "
                         f"{type(camera).__name__}") from None
    if view.shape != (4, 4) or proj.shape != (4, 4):
        raise ValueError("camera.view and camera.projection() must be (4, 4) matrices")
    if not np.all(view[3] == (0.0, 0.0, 0.0, 1.0)):
        raise ValueError("metric depth needs an affine view matrix (last row 0 0 0 1)")
    eye = -np.linalg.solve(view[:3, :3], view[:3, 3])
    ortho = bool(np.all(proj[3, :3] == 0.0))
    return view, proj, eye, ortho


def _view_axis(view: np.ndarray) -> np.ndarray:
    """Unit world-space direction the camera looks along (eye-space −Z)."""
    fwd = np.linalg.solve(view[:3, :3], [0.0, 0.0, -1.0])
    return fwd / np.linalg.norm(fwd)


#: `camera_axes`' result: view, projection, eye, view axis, orthographic
CameraAxes = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]


def camera_axes(camera: Any, width: int, height: int) -> CameraAxes:
    """(view float64 (4, 4), projection float64 (4, 4), eye float64 (3,), unit view axis
    float64 (3,), orthographic) of a `clraster.Camera`-like object (``view`` and
    ``projection(width, height)``): what the metric outputs are measured from, here and in
    the device's resolve stage. ValueError for a camera without them or a non-affine view."""
    view, proj, eye, ortho = _camera_frame(camera, width, height)
    return view, proj, eye, _view_axis(view), ortho


def _metric(frame: FrameBuffers, camera: Any, target: Any, kind: str) -> np.ndarray:
    """(H, W) float32 linear depth or distance (`kind`), inf on the background."""
    made = resolved_output(frame, kind, camera)
    if made is not None:
        return made
    h, w = frame.triangle_id.shape
    view, proj, eye, ortho = _camera_frame(camera, w, h)
    fwd = _view_axis(view)
    out = np.full((h, w), np.inf, np.float32)
    exact = target is not None
    if exact:
        pts = points(frame, target)
        ys, xs = pts.pixels[:, 1], pts.pixels[:, 0]
        offset = pts.points - eye
    else:
        # Back through the projection: pixel centre (x + 0.5, y + 0.5) and window depth d
        # → NDC (x_w/W·2 − 1, 1 − y_w/H·2, 2d − 1) → eye space → world offset from the eye.
        ys, xs = np.nonzero(np.asarray(frame.triangle_id) >= 0)
        d = np.asarray(frame.depth, np.float64)[ys, xs]
        zn = 1.0 - 2.0 * d if frame.reversed_z else 2.0 * d - 1.0   # (1 − z/w)/2 or (z/w + 1)/2
        ndc = np.stack([(xs + 0.5) / w * 2.0 - 1.0, 1.0 - (ys + 0.5) / h * 2.0,
                        zn, np.ones_like(d)], axis=1)
        e = ndc @ np.linalg.inv(proj).T
        e = e[:, :3] / e[:, 3:]
        offset = e @ np.linalg.inv(view[:3, :3]).T     # eye-space origin is the eye
    # (the resolve kernel's sums: the exact path gives the device's bits)
    along = dot_rows(offset, fwd) if exact else offset @ fwd
    if kind == "linear_depth" or ortho:
        # an orthographic camera's rays are parallel to the view axis: the distance along
        # a ray is the depth from the image plane through the eye
        out[ys, xs] = along
    else:
        out[ys, xs] = np.sqrt(dot_rows(offset, offset)) if exact else np.linalg.norm(offset,
                                                                                      axis=1)
    return out


def linear_depth(frame: FrameBuffers, camera: Any, target: Any = None) -> np.ndarray:
    """(H, W) float32 depth along the camera's view axis, in scene units (for a rigid view:
    −z in eye space); inf on the background. See `Frame.linear_depth`."""
    return _metric(frame, camera, target, "linear_depth")


def distance(frame: FrameBuffers, camera: Any, target: Any = None) -> np.ndarray:
    """(H, W) float32 distance from the eye to the visible surface along each pixel's ray,
    in scene units; inf on the background. See `Frame.distance`."""
    return _metric(frame, camera, target, "distance")


def normals(frame: FrameBuffers, target: Any, smooth: bool = False, space: str = "world",
            camera: Any = None) -> np.ndarray:
    """(H, W, 3) float32 unit normals of the visible surface, zeros on the background.

    World space: `clraster.shade.pixel_normals` (face normals, or area-weighted vertex
    normals interpolated with the barycentrics; a scene instance's through the inverse
    transpose of its transform, outward also when it mirrors — glTF's rule). Camera space:
    those rotated into OpenGL eye space (x right, y up, z towards the viewer) by the
    inverse transpose of the view's 3×3 part, renormalized.
    """
    _check_space(space, camera, "normals")
    name = ("smooth_" if smooth else "") + ("camera_normals" if space == "camera" else "normals")
    made = resolved_output(frame, name, camera if space == "camera" else None)
    if made is not None:
        return made
    n = pixel_normals(frame, _as_geometry(target), smooth=smooth)
    if space == "world":
        return n
    h, w = frame.triangle_id.shape
    view, _, _, _ = _camera_frame(camera, w, h)
    m = np.linalg.inv(view[:3, :3]).T.reshape(-1)
    flat = unit_rows(mat3_rows(m, n.reshape(-1, 3).astype(np.float64)))
    return flat.reshape(n.shape).astype(np.float32)


# -- files ----------------------------------------------------------------------------------

def check_output_path(path: str | os.PathLike, what: str, *, target: Any = None,
                      camera: Any = None) -> Path:
    """Refuse, before any work, an output that cannot be written: unknown `what`, an
    extension missing or unknown, one that cannot hold `what`, or a missing camera/target.
    Returns the path. (The command line calls this before rendering.)"""
    if what not in OUTPUTS:
        raise ValueError(f"unknown output {what!r}; choose one of {', '.join(OUTPUTS)}")
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in FORMATS:
        known = ", ".join(FORMATS)
        raise ValueError(f"{str(p)!r}: unknown or missing file extension {ext or '(none)'!r}; "
                         f"the extension picks the format: {known}")
    if what not in FORMATS[ext]:
        fits = ", ".join(e for e, ws in FORMATS.items() if what in ws)
        raise ValueError(f"{str(p)!r}: a {ext} file cannot hold {what!r}; use one of {fits}")
    if what in _NEEDS_CAMERA and camera is None:
        raise ValueError(f"{what!r} needs the camera the frame was rendered with (camera=...)")
    if what in _NEEDS_TARGET and target is None:
        raise ValueError(f"{what!r} needs the target the frame was rendered from (target=...)")
    return p


class _Options(NamedTuple):
    """`write_output`'s options with their defaults filled in."""

    depth_scale: float
    smooth: bool
    space: str


def check_depth_scale(depth_scale: Any) -> float:
    """``depth_scale`` as a float, or a ValueError unless it is a finite number > 0."""
    try:
        scale = float(depth_scale)
    except (TypeError, ValueError):
        scale = float("nan")
    if isinstance(depth_scale, bool) or not (np.isfinite(scale) and scale > 0.0):
        raise ValueError(f"depth_scale must be a finite number > 0 (PNG units per scene "
                         f"unit), got {depth_scale!r}")
    return scale


def check_output_options(what: str, ext: str, *, target: Any = None, camera: Any = None,
                         depth_scale: float | None = None, smooth: bool | None = None,
                         space: str | None = None, shade_options: dict | None = None
                         ) -> _Options:
    """Refuse the options output `what` would ignore in format `ext` (None: not given):
    ``target``, ``camera``, ``depth_scale``, ``smooth``, ``space`` and shade options each
    count only where the module docstring says they are read. Returns (depth_scale, smooth,
    space) with the defaults (1000.0, False, "world") for those not given.

    Raises:
        ValueError: naming the options `what` does not read, and what does read them.
    """
    given = {"target": target, "camera": camera, "depth_scale": depth_scale,
             "smooth": smooth, "space": space}
    resolved_space = "world" if space is None else space
    if what in ("normals", "points"):
        _check_space(resolved_space, camera, what)
    ignored = []
    for name, value in given.items():
        if value is None:
            continue
        readers = _READ_BY[name]
        if name == "camera" and what in ("normals", "points") and resolved_space == "camera":
            continue
        if name == "depth_scale" and what in readers and ext != ".png":
            ignored.append(f"depth_scale (only a .png of {what} is scaled; {ext} holds "
                           f"float32 scene units)")
        elif what not in readers:
            also = (" (and normals / points with space='camera')" if name == "camera"
                    else " (in a .png)" if name == "depth_scale" else "")
            ignored.append(f"{name} (read by {', '.join(readers)}{also})")
    if shade_options and what != "shaded":
        ignored.append(f"{', '.join(sorted(shade_options))} (shade options: read by shaded)")
    if ignored:
        raise ValueError(f"output {what!r} does not use {'; '.join(ignored)}: leave "
                         f"{'it' if len(ignored) == 1 else 'them'} out")
    return _Options(1000.0 if depth_scale is None else check_depth_scale(depth_scale),
                    False if smooth is None else bool(smooth), resolved_space)


#: ext → None where imageio here writes it, else why not (probed once per process)
_WRITABLE: dict[str, str | None] = {}


def check_writable(what: str, ext: str) -> None:
    """Refuse, before any work, a format this installation cannot write `what` in: an
    (H, W, 3) float32 TIFF (normals, barycentrics) without the `tifffile` package, or EXR
    without an imageio plugin that writes it. (`write_output` finds both while encoding,
    after computing; batch paths call this once up front, not once per view.)"""
    float3 = what == "bary" or (what == "normals" and ext != ".png")
    if ext in (".tif", ".tiff") and float3:
        try:
            import tifffile  # noqa: F401
        except ImportError:
            raise ValueError(f"writing {what} ((H, W, 3) float32) as TIFF needs the tifffile "
                             f"package (pip install tifffile); or write .npy / .npz") from None
    if ext == ".exr":
        if ext not in _WRITABLE:
            try:
                _encode(np.zeros((1, 1), np.float32), ext, what)
                _WRITABLE[ext] = None
            except ValueError as exc:
                _WRITABLE[ext] = str(exc)
        if _WRITABLE[ext] is not None:
            raise ValueError(str(_WRITABLE[ext]))


def _image_array(frame: FrameBuffers, what: str, ext: str, *, target: Any, camera: Any,
                 options: _Options, shade_options: dict) -> Any:
    """The array (or (FramePoints, normals)) to write for `what` in format `ext`."""
    if what == "points":
        pts = points(frame, target, space=options.space, camera=camera)
        return pts, point_normals(frame, target, smooth=options.smooth, space=options.space,
                                  camera=camera)
    if what == "depth":
        a = np.asarray(frame.depth, np.float32)
        if ext == ".png":
            return np.round(np.clip(a.astype(np.float64), 0.0, 1.0) * _U16_MAX).astype(np.uint16)
        return a
    if what == "bary":
        return np.asarray(frame.need_barycentrics(), np.float32)
    if what == "mask":
        m = resolved_output(frame, "mask")
        m = np.asarray(frame.triangle_id) >= 0 if m is None else m
        return m if ext in (".npy", ".npz") else m.astype(np.uint8) * np.uint8(255)
    if what in _NEEDS_CAMERA:
        a = _metric(frame, camera, target, what)
        if ext != ".png":
            return a
        scale = options.depth_scale
        fin = np.isfinite(a)
        q = np.zeros(a.shape, np.float64)
        q[fin] = np.round(a[fin].astype(np.float64) * scale)
        if fin.any() and (q[fin].min() < 1 or q[fin].max() > _U16_MAX):
            lo, hi = float(a[fin].min()), float(a[fin].max())
            raise ValueError(f"{what} spans {lo:.6g}..{hi:.6g} scene units: at depth_scale="
                             f"{scale:g} that is {q[fin].min():.0f}..{q[fin].max():.0f}, "
                             f"outside a 16-bit PNG's 1..65535 (0 means no depth); choose "
                             f"another depth_scale, or write .tiff / .npy (float32)")
        return q.astype(np.uint16)
    if what == "ids":
        ids = np.asarray(frame.triangle_id, np.int32)
        if ext != ".png":
            return ids
        top = int(ids.max()) if ids.size else -1
        if top + 1 > _U16_MAX:
            raise ValueError(f"triangle ids reach {top:,}: a 16-bit PNG holds id + 1 up to "
                             f"65535 only; write the ids as .npy, .npz or .tiff (int32)")
        return (ids + 1).astype(np.uint16)
    if what == "normals":
        n = normals(frame, target, smooth=options.smooth, space=options.space, camera=camera)
        if ext == ".png":
            rgb = np.round((n.astype(np.float64) + 1.0) * 0.5 * 255.0).astype(np.uint8)
            rgb[~(np.asarray(frame.triangle_id) >= 0)] = 0
            return rgb
        return n
    return shade(frame, target, **shade_options)


def _encode(arr: np.ndarray, ext: str, what: str) -> bytes:
    """Image bytes of `arr` in format `ext` through imageio."""
    import imageio.v3 as iio

    if ext in (".tif", ".tiff"):
        try:
            import tifffile  # noqa: F401
        except ImportError:
            pillow_ok = ((arr.ndim == 2 and arr.dtype in (np.float32, np.int32, np.uint16))
                         or (arr.dtype == np.uint8 and arr.ndim in (2, 3)))
            if not pillow_ok:
                raise ValueError(f"writing {what} ({arr.dtype}, shape {arr.shape}) as TIFF "
                                 f"needs the tifffile package (pip install tifffile); or "
                                 f"write .npy / .npz") from None
            return iio.imwrite("<bytes>", arr, extension=ext, plugin="pillow")
        return iio.imwrite("<bytes>", arr, extension=ext, plugin="tifffile")
    if ext == ".exr":
        try:
            with warnings.catch_warnings():   # plugins that cannot write EXR warn first
                warnings.simplefilter("ignore")
                return iio.imwrite("<bytes>", arr.astype(np.float32), extension=ext)
        except Exception as exc:   # imageio raises several types when no plugin can
            raise ValueError(f"writing EXR needs an imageio plugin that writes OpenEXR (e.g. "
                             f"FreeImage: imageio.plugins.freeimage.download()), and none "
                             f"could ({type(exc).__name__}: {exc}); write .tiff or .npy "
                             f"(float32) instead") from None
    return iio.imwrite("<bytes>", arr, extension=ext)


#: a PLY point cloud's vertex: position and unit normal, float32 little-endian
_PLY_FIELDS = ("x", "y", "z", "nx", "ny", "nz")
_PLY_VERTEX = np.dtype([(c, "<f4") for c in _PLY_FIELDS])


def _ply_bytes(xyz: np.ndarray, nrm: np.ndarray) -> bytes:
    """A binary little-endian PLY of one ``vertex`` element (x y z nx ny nz float32)."""
    rows = np.empty(len(xyz), _PLY_VERTEX)
    for k, c in enumerate("xyz"):
        rows[c] = xyz[:, k]
        rows["n" + c] = nrm[:, k]
    props = "".join(f"property float {c}\n" for c in _PLY_FIELDS)
    header = (f"ply\nformat binary_little_endian 1.0\ncomment written by clraster\n"
              f"element vertex {len(xyz)}\n{props}end_header\n")
    return header.encode("ascii") + rows.tobytes()


def _encode_points(pts: FramePoints, nrm: np.ndarray, ext: str) -> bytes:
    if ext == ".ply":
        return _ply_bytes(pts.points, nrm)
    buf = io.BytesIO()
    if ext == ".npy":
        np.save(buf, np.hstack([pts.points, nrm.astype(np.float64)]))
    else:
        np.savez(buf, points=pts.points, normals=nrm, ids=pts.ids, pixels=pts.pixels)
    return buf.getvalue()


def _write_atomic(path: Path, data: bytes) -> None:
    """Write `data` to exactly `path` (a temporary file in the same folder whose name fits
    wherever `path`'s does, then a rename: `clraster.atomic.write_atomic`)."""
    write_atomic(path, data)


def write_output(path: str | os.PathLike, frame: FrameBuffers, what: str, *, target: Any = None,
                 camera: Any = None, depth_scale: float | None = None,
                 smooth: bool | None = None, space: str | None = None,
                 **shade_options: Any) -> Path:
    """Write one output of `frame` to exactly `path`, in the format its extension names.

    Args:
        path: the file; its extension picks the format (module docstring).
        frame: the rendered `Frame`.
        what: one of `OUTPUTS`.
        target: the Mesh / Scene / trimesh object the frame was rendered from ("normals",
            "shaded", "points"; optional for "linear_depth"/"distance", which it makes exact).
        camera: the camera it was rendered with ("linear_depth", "distance"; "normals" and
            "points" with ``space="camera"``).
        depth_scale: for "linear_depth"/"distance" in a .png only: PNG value =
            ``round(value · depth_scale)``, value in scene units (default 1000: millimetres
            for a scene in metres).
        smooth: for "normals" and the normals of "points" (`Frame.normals`), and "shaded";
            default False.
        space: "world" (default) or "camera", for "normals" and "points".
        shade_options: passed to `clraster.shade.shade` for "shaded".

    Returns:
        The path written.

    Raises:
        ValueError: unknown `what` or extension, a format that cannot hold the data (ids
            or depths beyond 16 bits in a PNG, EXR without a plugin, float (H, W, 3) TIFF
            without tifffile), a missing camera/target, an option `what` does not read
            (`check_output_options`) — all before the file is touched.
    """
    p = check_output_path(path, what, target=target, camera=camera)
    ext = p.suffix.lower()
    options = check_output_options(what, ext, target=target, camera=camera,
                                   depth_scale=depth_scale, smooth=smooth, space=space,
                                   shade_options=shade_options)
    if what == "shaded":
        shade_options = {"smooth": options.smooth, **shade_options}
    data = _image_array(frame, what, ext, target=target, camera=camera, options=options,
                        shade_options=shade_options)
    if isinstance(data, tuple):
        blob = _encode_points(data[0], data[1], ext)
    elif ext == ".npy":
        buf = io.BytesIO()
        np.save(buf, data)
        blob = buf.getvalue()
    elif ext == ".npz":
        buf = io.BytesIO()
        np.savez(buf, **{what: data})
        blob = buf.getvalue()
    else:
        blob = _encode(np.ascontiguousarray(data), ext, what)
    _write_atomic(p, blob)
    return p
