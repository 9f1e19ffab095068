"""Validation of inputs: the one home of the checks shared by the OpenCL renderer, the NumPy
twin, the cameras, scenes, generators and the command lines (image sizes, integers, 4×4
matrices, boxes, yes/no options, WIDTHxHEIGHT arguments). Each raises ValueError (argparse's
ArgumentTypeError for command-line text) saying what was wrong.
"""

from __future__ import annotations

import argparse

import numpy as np
import numpy.typing as npt

from .config import CULL_MODES, MAX_IMAGE_SIZE


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
    if not np.all(np.isfinite(arr)):
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
    lo = np.ascontiguousarray(np.asarray(mins, dtype=dtype))
    hi = np.ascontiguousarray(np.asarray(maxs, dtype=dtype))
    if lo.ndim == 1 and lo.size == 0:
        lo = lo.reshape(0, 3)
    if hi.ndim == 1 and hi.size == 0:
        hi = hi.reshape(0, 3)
    if lo.ndim != 2 or lo.shape[1] != 3 or hi.shape != lo.shape:
        raise ValueError(f"{names[0]} and {names[1]} must both have shape (K, 3), got "
                         f"{lo.shape} and {hi.shape}")
    return lo, hi


def check_cull(cull: str) -> str:
    """A face-culling mode: one of CULL_MODES ("back", "front", "none")."""
    if not isinstance(cull, str) or cull not in CULL_MODES:
        raise ValueError(f"cull must be one of {sorted(CULL_MODES)}, got {cull!r}")
    return cull


def view_projection(camera, width: int, height: int) -> np.ndarray:
    """float64 (4, 4) view-projection of ``camera`` for this image size, validated."""
    try:
        m = np.asarray(camera.view_projection(width, height), dtype=np.float64)
    except AttributeError:
        raise ValueError(f"expected a clraster.Camera, got {type(camera).__name__}") from None
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError("camera.view_projection() must return a finite (4, 4) matrix")
    return m


def mvp_matrix(camera, width: int, height: int) -> np.ndarray:
    """Row-major float32 (4, 4) view-projection matrix of ``camera`` for this image size."""
    m = view_projection(camera, width, height)
    with np.errstate(over="ignore"):
        m32 = m.astype(np.float32)
    if not np.all(np.isfinite(m32)):
        raise ValueError("the view-projection matrix overflows float32")
    return np.ascontiguousarray(m32)


def check_flag(value: object, name: str) -> bool:
    """A yes/no option: True/False (or NumPy bool) only. Strings such as "no" are truthy,
    so accepting any object would silently turn an option on."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)
