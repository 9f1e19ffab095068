"""Validation of inputs: the one home of the checks shared by the OpenCL renderer, the NumPy
twin, the cameras, scenes, generators and the command lines (image sizes, integers, 4×4
matrices, boxes, cameras, yes/no options, WIDTHxHEIGHT arguments). Each raises ValueError
(argparse's ArgumentTypeError for command-line text) saying what was wrong.

Plain NumPy over the config and the kernels' layout: every layer may use it, and it imports
nothing else of clraster (what a caller renders becomes a Mesh or Scene in
`clraster.inputs.as_target`, above the meshes and scenes).
"""

from __future__ import annotations

import argparse
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from .config import MAX_IMAGE_SIZE
from .layout import CULL_MODES, USER_PLANES_MAX


class CameraLike(Protocol):
    """What the renderers take as a camera: a `clraster.Camera`, or any object whose
    ``view_projection(width, height)`` returns a (4, 4) view-projection matrix (OpenGL
    conventions, column vectors: ``clip = M @ [x, y, z, 1]``)."""

    def view_projection(self, width: int, height: int) -> npt.ArrayLike: ...


def check_size(width: int, height: int) -> tuple[int, int]:
    """Validate an image size; returns it as plain ints."""
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise ValueError(f"{name} must be an integer, got {v!r}")
        if not 0 < v <= MAX_IMAGE_SIZE:
            raise ValueError(f"{name} must be in 1..{MAX_IMAGE_SIZE} pixels, got {v}")
    return int(width), int(height)


def parse_size(text: str) -> tuple[int, int]:
    """A command-line image size ``WIDTHxHEIGHT`` (e.g. ``1280x720``), checked like
    `check_size`; argparse's ArgumentTypeError otherwise."""
    parts = text.lower().split("x")
    try:
        if len(parts) != 2:
            raise ValueError
        w, h = int(parts[0]), int(parts[1])
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT in pixels, e.g. 1280x720, got {text!r}") from None
    if not (0 < w <= MAX_IMAGE_SIZE and 0 < h <= MAX_IMAGE_SIZE):
        raise argparse.ArgumentTypeError(
            f"width and height must be in 1..{MAX_IMAGE_SIZE}, got {text!r}")
    return w, h


def parse_positive_int(text: str) -> int:
    """A command-line count: an integer >= 1; argparse's ArgumentTypeError otherwise."""
    try:
        v = int(text)
    except ValueError:
        v = 0
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return v


def check_int(value: object, name: str, minimum: int) -> int:
    """An integer (not a bool) >= ``minimum``, as a plain int."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def check_mat4(value: npt.ArrayLike, name: str, *, read_only: bool = False) -> np.ndarray:
    """``value`` as a finite float64 (4, 4) copy (the caller's array is never aliased),
    read-only if asked."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a 4×4 real matrix; could not convert "
                         f"{type(value).__name__} ({exc})") from exc
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be a 4×4 real matrix, got dtype {arr.dtype}")
    if arr.shape != (4, 4):
        raise ValueError(f"{name} must have shape (4, 4), got shape {arr.shape}")
    arr = arr.astype(np.float64, copy=True)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite; it contains NaN or Inf")
    if read_only:
        arr.flags.writeable = False
    return arr


def check_boxes(mins: npt.ArrayLike, maxs: npt.ArrayLike, dtype: type = np.float64, *,
                names: tuple[str, str] = ("box mins", "box maxs")
                ) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes as C-contiguous ``dtype`` (K, 3) arrays each (an empty 1-D input
    is read as (0, 3)); ValueError unless both have shape (K, 3). Values (NaN, order) are
    not checked: callers treat non-finite boxes as unbounded."""
    lo: np.ndarray = np.ascontiguousarray(np.asarray(mins, dtype=dtype))
    hi: np.ndarray = np.ascontiguousarray(np.asarray(maxs, dtype=dtype))
    if lo.ndim == 1 and lo.size == 0:
        lo = lo.reshape(0, 3)
    if hi.ndim == 1 and hi.size == 0:
        hi = hi.reshape(0, 3)
    if lo.ndim != 2 or lo.shape[1] != 3 or hi.shape != lo.shape:
        raise ValueError(f"{names[0]} and {names[1]} must both have shape (K, 3), got "
                         f"{lo.shape} and {hi.shape}")
    return lo, hi


def check_clip_planes(planes: Any) -> np.ndarray | None:
    """User clip planes: None (or an empty list) → None, else float64 (K, 4) rows
    (a, b, c, d), 1 <= K <= USER_PLANES_MAX (8), each keeping the world-space points with
    a·x + b·y + c·z + d >= 0. ValueError for another shape, non-finite values, more than 8
    planes, or a zero normal (a, b, c) (such a plane keeps everything or nothing)."""
    if planes is None:
        return None
    try:
        p = np.array(planes, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"clip_planes must be (K, 4) numbers (a, b, c, d), got "
                         f"{planes!r}") from None
    if p.size == 0:
        return None
    if p.ndim == 1 and p.shape[0] == 4:
        p = p.reshape(1, 4)
    if p.ndim != 2 or p.shape[1] != 4:
        raise ValueError(f"clip_planes must have shape (K, 4): rows (a, b, c, d) keeping "
                         f"a*x + b*y + c*z + d >= 0; got shape {p.shape}")
    if p.shape[0] > USER_PLANES_MAX:
        raise ValueError(f"at most {USER_PLANES_MAX} clip planes (as OpenGL's "
                         f"GL_MAX_CLIP_DISTANCES), got {p.shape[0]}: combine or drop some")
    if not np.isfinite(p).all():
        raise ValueError("clip_planes must be finite (no NaN or Inf)")
    zero = ~np.any(p[:, :3] != 0.0, axis=1)
    if zero.any():
        raise ValueError(f"clip plane {int(np.flatnonzero(zero)[0])} has a zero normal "
                         "(a, b, c) = 0: it would keep everything or nothing")
    return np.ascontiguousarray(p)


def check_cull(cull: str) -> str:
    """A face-culling mode: one of CULL_MODES ("back", "front", "none")."""
    if not isinstance(cull, str) or cull not in CULL_MODES:
        raise ValueError(f"cull must be one of {sorted(CULL_MODES)}, got {cull!r}")
    return cull


def view_projection(camera: CameraLike, width: int, height: int) -> np.ndarray:
    """float64 (4, 4) view-projection of ``camera`` for this image size, validated."""
    try:
        m = np.asarray(camera.view_projection(width, height), dtype=np.float64)
    except AttributeError:
        raise ValueError(f"expected a clraster.Camera, got {type(camera).__name__}") from None
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise ValueError("camera.view_projection() must return a finite (4, 4) matrix")
    return m


def mvp_matrix(camera: CameraLike, width: int, height: int) -> np.ndarray:
    """Row-major float32 (4, 4) view-projection matrix of ``camera`` for this image size."""
    m = view_projection(camera, width, height)
    with np.errstate(over="ignore"):
        m32 = m.astype(np.float32)
    if not np.all(np.isfinite(m32)):
        raise ValueError("the view-projection matrix overflows float32")
    return np.ascontiguousarray(m32)


#: Per-pixel outputs the resolve stage makes on the device from ids, barycentrics and the
#: scene's geometry, only when asked for (`Renderer.render(outputs=...)`; the
#: `clraster.Frame` methods return them): names as the batch outputs
#: (`clraster.scale.batch.OUTPUTS`) call them.
RESOLVE_OUTPUTS = ("mask", "linear_depth", "distance", "points", "normals", "smooth_normals",
                   "camera_normals", "smooth_camera_normals")
#: Frame outputs `Renderer.render(outputs=...)` can choose among: the raster's buffers in
#: Frame field order, then the resolve stage's.
RENDER_OUTPUTS = ("depth", "ids", "bary") + RESOLVE_OUTPUTS


def check_render_outputs(outputs: object) -> tuple[str, ...]:
    """``outputs`` of `Renderer.render`: a name or a sequence of distinct names out of
    `RENDER_OUTPUTS`, at least one. Returns the names, as a tuple (depth and ids are
    always made: the depth test needs both)."""
    names = (outputs,) if isinstance(outputs, str) else outputs
    out: tuple = ()
    try:
        out = tuple(names)   # type: ignore[arg-type]  # checked just below
    except TypeError:
        pass
    if (not out or len(set(out)) != len(out)
            or not all(isinstance(o, str) and o in RENDER_OUTPUTS for o in out)):
        raise ValueError(f"outputs must be distinct names out of {', '.join(RENDER_OUTPUTS)}"
                         f" (at least one), got {outputs!r}")
    return out


def check_flag(value: object, name: str) -> bool:
    """A yes/no option: True/False (or NumPy bool) only. Strings such as "no" are truthy,
    so accepting any object would silently turn an option on."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)
