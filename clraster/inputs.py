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
    if cull not in CULL_MODES:
        raise ValueError(f"cull must be one of {sorted(CULL_MODES)}, got {cull!r}")
    return cull


#: Faces per draw. Piece, entry and offset counters are int32; a triangle makes at most 14
#: pieces, so this keeps every counter exact.
MAX_FACES = 1 << 27


def check_mesh(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(vertices float32 (N, 3), faces int32 (M, 3)) of a `clraster.Mesh`-like object.

    A `clraster.Mesh` validated its indices when it was built (its arrays are read-only);
    any other object gets its indices checked here, since the kernels index with them.
    """
    try:
        v, f = mesh.vertices, mesh.faces
    except AttributeError:
        raise ValueError(f"expected a clraster.Mesh (with .vertices and .faces), got "
                         f"{type(mesh).__name__}") from None
    v = np.asarray(v)
    f = np.asarray(f)
    if v.dtype != np.float32 or v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"mesh.vertices must be float32 (N, 3), got {v.dtype} {v.shape}; "
                         "build it with clraster.Mesh(vertices, faces)")
    if f.dtype != np.int32 or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"mesh.faces must be int32 (M, 3), got {f.dtype} {f.shape}; "
                         "build it with clraster.Mesh(vertices, faces)")
    if f.shape[0] > MAX_FACES:
        raise ValueError(f"{f.shape[0]:,} faces in one draw; at most {MAX_FACES:,} are "
                         "supported: split the mesh")
    from .mesh import Mesh  # local: mesh.py is a sibling layer, imported only for the check

    if f.size and not (isinstance(mesh, Mesh) and not f.flags.writeable):
        lo, hi = int(f.min()), int(f.max())
        if lo < 0 or hi >= v.shape[0]:
            raise ValueError(f"mesh.faces index out of range: values span [{lo}, {hi}] for "
                             f"{v.shape[0]} vertices")
    return v, f


def mvp_matrix(camera, width: int, height: int) -> np.ndarray:
    """Row-major float32 (4, 4) view-projection matrix of ``camera`` for this image size."""
    try:
        m = np.asarray(camera.view_projection(width, height), dtype=np.float64)
    except AttributeError:
        raise ValueError(f"expected a clraster.Camera, got {type(camera).__name__}") from None
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError("camera.view_projection() must return a finite (4, 4) matrix")
    m32 = m.astype(np.float32)
    if not np.all(np.isfinite(m32)):
        raise ValueError("the view-projection matrix overflows float32")
    return np.ascontiguousarray(m32)
