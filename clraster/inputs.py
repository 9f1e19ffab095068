"""Validation of the inputs shared by the OpenCL renderer and the NumPy twin."""

from __future__ import annotations

import numpy as np

from .config import CULL_MODES, MAX_IMAGE_SIZE


def check_size(width: int, height: int) -> tuple[int, int]:
    """Validate an image size; returns it as plain ints."""
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise ValueError(f"{name} must be an integer, got {v!r}")
        if not 0 < v <= MAX_IMAGE_SIZE:
            raise ValueError(f"{name} must be in 1..{MAX_IMAGE_SIZE} pixels, got {v}")
    return int(width), int(height)


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
