"""Turning a rendered frame into pictures: flat Lambert shading and depth images.

Both functions work on the frame's buffers only (``triangle_id`` and ``depth``), so they
apply equally to frames from the OpenCL renderer and from the NumPy reference.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import numpy.typing as npt

from .mesh import Mesh

__all__ = ["DEFAULT_LIGHT_DIR", "depth_image", "shade"]

#: World-space direction *towards* the light used when none is given: up, right, front.
DEFAULT_LIGHT_DIR = (0.35, 0.85, 0.45)
_ALBEDO = np.array([0.80, 0.82, 0.88])  # a light blue-grey
_AMBIENT = 0.22
#: Grey levels of the depth image: nearest covered pixel → 0, farthest → _DEPTH_FAR;
#: background is 255, so it stays distinguishable from the farthest surface.
_DEPTH_FAR = 235


class _FrameLike(Protocol):
    @property
    def triangle_id(self) -> np.ndarray: ...


def _ids(frame: _FrameLike, mesh: Mesh) -> np.ndarray:
    ids = np.asarray(frame.triangle_id)
    if ids.ndim != 2 or ids.dtype.kind not in "iu":
        raise ValueError(f"frame.triangle_id must be an (H, W) integer array, got shape "
                         f"{ids.shape} dtype {ids.dtype}")
    if ids.size and (int(ids.min()) < -1 or int(ids.max()) >= mesh.n_faces):
        raise ValueError(f"frame.triangle_id holds ids outside [-1, {mesh.n_faces}) "
                         f"(range {int(ids.min())}..{int(ids.max())}): was the frame "
                         f"rendered from this mesh?")
    return ids


def shade(frame: _FrameLike, mesh: Mesh, *, light_dir: npt.ArrayLike | None = None,
          background: tuple[int, int, int] = (255, 255, 255)) -> np.ndarray:
    """Flat-shaded RGB image of `frame`: (H, W, 3) uint8, row 0 at the top.

    Each covered pixel gets the colour of its face: ``albedo · (ambient + (1 − ambient) ·
    |n · l|)`` with ``n`` the face's unit normal (:meth:`Mesh.face_normals`) and ``l`` the
    unit light direction. Lighting is two-sided (``|n · l|``), so open meshes and
    inconsistently wound faces look right with culling off. Faces with a zero normal
    (degenerate) get ambient only. Pixels with ``triangle_id == −1`` get `background`.

    Args:
        frame: anything with ``triangle_id``, an (H, W) integer array of face indices
            into `mesh` (−1 = background), e.g. a :class:`clraster.Frame`.
        mesh: the mesh the frame was rendered from.
        light_dir: world-space direction towards the light, (3,), any non-zero length;
            default :data:`DEFAULT_LIGHT_DIR`.
        background: RGB 0..255 for uncovered pixels.

    Raises:
        ValueError: ids out of range for `mesh`, a zero or non-finite light direction,
            or a background that is not three values in 0..255.
    """
    ids = _ids(frame, mesh)
    light = np.asarray(DEFAULT_LIGHT_DIR if light_dir is None else light_dir, dtype=np.float64)
    if light.shape != (3,) or not np.all(np.isfinite(light)) or not np.any(light):
        raise ValueError(f"light_dir must be a finite, non-zero 3-vector, got {light.tolist()}")
    light /= np.linalg.norm(light)
    bg = np.asarray(background)
    if bg.shape != (3,) or bg.dtype.kind not in "iu" or np.any((bg < 0) | (bg > 255)):
        raise ValueError(f"background must be three integers in 0..255 (R, G, B), "
                         f"got {background!r}")

    lambert = np.abs(mesh.face_normals().astype(np.float64) @ light)  # (M,)
    face_rgb = _ALBEDO[None, :] * (_AMBIENT + (1.0 - _AMBIENT) * lambert[:, None])
    # Palette: row 0 is the background, row i + 1 face i, so ids index it directly.
    palette = np.empty((mesh.n_faces + 1, 3), dtype=np.uint8)
    palette[0] = bg
    palette[1:] = np.clip(np.rint(face_rgb * 255.0), 0, 255)
    return palette[ids.astype(np.int64) + 1]


def depth_image(depth: npt.ArrayLike) -> np.ndarray:
    """Greyscale view of a window-depth buffer: (H, W) uint8, near = dark.

    Covered pixels (``depth < 1.0``; the buffer is cleared to 1.0) are mapped linearly from
    the nearest (0) to the farthest covered depth (235); background pixels are 255. When
    all covered pixels share one depth they are 0; an all-background buffer is all 255.
    Non-finite depths count as background.

    Args:
        depth: (H, W) window depth ``(z/w + 1) / 2`` in [0, 1], e.g. ``Frame.depth``.
    """
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim != 2:
        raise ValueError(f"depth must be an (H, W) array, got shape {d.shape}")
    covered = np.isfinite(d) & (d < 1.0)
    out = np.full(d.shape, 255, dtype=np.uint8)
    if covered.any():
        vals = d[covered]
        lo, hi = vals.min(), vals.max()
        scale = _DEPTH_FAR / (hi - lo) if hi > lo else 0.0
        out[covered] = np.clip(np.rint((vals - lo) * scale), 0, _DEPTH_FAR).astype(np.uint8)
    return out
