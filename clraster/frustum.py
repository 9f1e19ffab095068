"""Frustum math on the host: planes of a view-projection matrix, its eye, and the
classification of spheres and boxes against six planes.

Used by the draw-list builder (:mod:`clraster.cull`), the renderer (eye point) and the
tests. Everything here is float64 NumPy; the box / sphere primitives it shares with the
BVH live in :mod:`clraster.bvh`.

Frustum planes (Gribb & Hartmann, "Fast extraction of viewing frustum planes from the
world-view-projection matrix", 2001): with rows r0..r3 of VP, a point p is inside iff
−w <= x, y, z <= w for (x, y, z, w) = VP·[p, 1], i.e. iff the six planes
r3 + r0, r3 − r0, r3 + r1, r3 − r1, r3 + r2, r3 − r2 (left, right, bottom, top, near, far)
are all >= 0 at p. For an object transform M the same planes in object space are the rows
times M (plane·(M·p) = (plane·M)·p), so no bounding volume is ever transformed: boxes and
spheres are tested where they were computed, which stays exact under any affine M
(non-uniform scale included).

Margins. The renderer evaluates those inequalities in float32. A plane row's value at p is a
sum of products whose magnitude is at most ``scale · [|p|, 1]`` with ``scale = |r3| + |ri|``
(elementwise; in object space ``(|r3| + |ri|) @ |M|``, which also covers evaluating
``VP @ (M @ p)`` in two steps); its float32 rounding error is a small multiple of 2**−24
times that. INSIDE therefore requires every plane value to be >= ``inside_margin`` (default
1e-5, ~170× float32's unit roundoff) times that magnitude over the whole volume, and
OUTSIDE requires some plane value to stay below −``outside_margin`` times it: what the
culler calls INSIDE passes every clip test in float32 too, and what it removes fails one.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from .bvh import (
    DEFAULT_MARGIN,
    Visibility,
    box_extremes,
    box_magnitudes,
    check_mask,
    check_planes,
    classify_extremes,
    sphere_extremes,
)
from .inputs import check_boxes, check_mat4

__all__ = [
    "DEFAULT_MARGIN", "PLANE_NAMES", "Visibility", "check_view_proj", "classify_aabbs",
    "classify_spheres", "eye_and_flip", "eye_from_view_proj", "frustum_plane_scales",
    "frustum_planes", "normalize_planes", "raw_planes", "view_proj_flips",
]

PLANE_NAMES = ("left", "right", "bottom", "top", "near", "far")


# -- matrices and planes ----------------------------------------------------------------

def check_view_proj(view_proj: npt.ArrayLike) -> np.ndarray:
    """`view_proj` as a float64 (4, 4) copy (also used for object transforms).

    Raises:
        ValueError: not convertible to a real (4, 4) matrix, or not finite.
    """
    return check_mat4(view_proj, "view_proj")


def raw_planes(vp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unnormalized Gribb–Hartmann rows (6, 4) and their magnitude rows (6, 4).

    vp: float64 (4, 4) (`check_view_proj`). Rows in `PLANE_NAMES` order, >= 0 inside; the
    magnitude rows are ``|r3| + |ri|`` (the margin scales before normalization, see the
    module docstring). Both are float64 and can be moved to object space by ``@ M`` and
    ``@ |M|`` before `normalize_planes`.
    """
    r = vp
    a = np.abs(vp)
    raw = np.stack([r[3] + r[0], r[3] - r[0], r[3] + r[1], r[3] - r[1], r[3] + r[2],
                    r[3] - r[2]])
    mag = np.stack([a[3] + a[0], a[3] + a[0], a[3] + a[1], a[3] + a[1], a[3] + a[2],
                    a[3] + a[2]])
    return raw, mag


def normalize_planes(raw: np.ndarray, mag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Divide plane rows (..., 6, 4) and their scales by the normal length. A plane with a
    zero normal (e.g. an infinitely far plane: constant sign everywhere) is divided by
    |d| instead, so its value is ±1 (or 0 if it is identically zero).

    Returns (planes, scales), float64, of the inputs' shape (..., 6, 4).
    """
    n = np.linalg.norm(raw[..., :3], axis=-1)
    n = np.where(n > 0.0, n, np.abs(raw[..., 3]))
    n = np.where(n > 0.0, n, 1.0)[..., None]
    return raw / n, mag / n


def frustum_planes(view_proj: npt.ArrayLike) -> np.ndarray:
    """The six frustum planes of an OpenGL-style view-projection matrix.

    Args:
        view_proj: (4, 4) world → clip for column vectors; a point p is inside iff
            −w <= x, y, z <= w for (x, y, z, w) = view_proj @ [p, 1].

    Returns:
        float64 (6, 4): rows (a, b, c, d) for left, right, bottom, top, near, far, each
        scaled so that (a, b, c) is a unit vector and ``a·x + b·y + c·z + d`` is the signed
        distance of (x, y, z) to the plane, >= 0 inside. A plane whose normal is zero (an
        infinitely distant far plane) is scaled to ``(0, 0, 0, ±1)``.
    """
    planes, _ = normalize_planes(*raw_planes(check_view_proj(view_proj)))
    return planes


def frustum_plane_scales(view_proj: npt.ArrayLike,
                         transform: npt.ArrayLike | None = None) -> np.ndarray:
    """Margin scales (6, 4) of the planes of ``view_proj @ transform``.

    Row k bounds the magnitude of the float32 terms of plane k: its value at p is off by a
    small multiple of 2**−24 · ``scales[k] · [|x|, |y|, |z|, 1]`` at most (see the module
    docstring). Scaled like `frustum_planes` of ``view_proj @ transform``.
    """
    vp = check_view_proj(view_proj)
    raw, mag = raw_planes(vp)
    if transform is not None:
        m = check_view_proj(transform)
        raw, mag = raw @ m, mag @ np.abs(m)
    return normalize_planes(raw, mag)[1]


def _cofactor_eye(vp: np.ndarray) -> np.ndarray:
    """c with c·q = det([x; y; w; q]) for the x, y, w rows of vp: their null vector."""
    p3 = vp[[0, 1, 3]]
    c = np.empty(4)
    for j in range(4):
        cols = [k for k in range(4) if k != j]
        c[j] = (-1.0) ** (3 + j) * np.linalg.det(p3[:, cols])
    return c


def eye_and_flip(vp: np.ndarray) -> tuple[np.ndarray, bool]:
    """(`eye_from_view_proj`, `view_proj_flips`) of a checked float64 (4, 4) `vp` at once.

    Raises:
        ValueError: as `eye_from_view_proj`.
    """
    # Move the world origin to (about) the eye first: the rows' norms grow with the camera's
    # distance from the origin, and so the degeneracy test below refused every camera
    # farther than ~1e6 units (georeferenced scenes). The least-squares point of the x, y
    # and w rows is the eye of a perspective view and a point of the view axis of an
    # orthographic one; a translation leaves the answer's meaning unchanged.
    p3 = vp[[0, 1, 3]]
    p0 = np.linalg.lstsq(p3[:, :3], -p3[:, 3], rcond=None)[0]
    if not np.all(np.isfinite(p0)):
        p0 = np.zeros(3)
    vp0 = vp.copy()
    vp0[:, 3] = vp[:, :3] @ p0 + vp[:, 3]
    c = _cofactor_eye(vp0)
    scale = float(np.prod(np.linalg.norm(vp0[[0, 1, 3]], axis=1)))
    if not np.linalg.norm(c) > 1e-12 * scale:
        raise ValueError("view_proj has linearly dependent x, y and w rows: it has no eye "
                         "point or viewing direction (a degenerate projection)")
    if abs(c[3]) > 1e-12 * np.linalg.norm(c):
        return np.append(c[:3] / c[3] + p0, 1.0), bool(c[3] > 0.0)
    d = c[:3] / np.linalg.norm(c[:3])
    return np.append(d, 0.0), bool(np.dot(vp[2, :3], d) < 0.0)


def eye_from_view_proj(view_proj: npt.ArrayLike) -> np.ndarray:
    """The homogeneous eye of a view-projection matrix, float64 (4,).

    The eye is the null vector of the x, y and w rows of VP (every point on a line through
    it projects to the same pixel). Perspective: ``(ex, ey, ez, 1)``, the eye point.
    Orthographic (w row constant): ``(dx, dy, dz, 0)`` with d the unit viewing direction,
    signed so that a face with normal n is clockwise in NDC (culled by cull="back") iff
    ``dot(n, d) > 0``.

    For a perspective eye e, a face with normal n through point p is clockwise in NDC iff
    ``dot(n, p − e) > 0`` — unless the projection mirrors (`view_proj_flips`), which swaps
    the two. (Derivation: det([x; y; w] of the three clip vertices) = −c_w·dot(n, e − p)
    where c = the cofactor vector of the x, y, w rows and e = c[:3] / c_w; its sign is the
    NDC orientation when all w > 0, and c_w < 0 for an unmirrored camera.)

    Raises:
        ValueError: not a finite (4, 4) matrix, or its x, y, w rows are linearly dependent.
    """
    return eye_and_flip(check_view_proj(view_proj))[0]


def view_proj_flips(view_proj: npt.ArrayLike) -> bool:
    """Whether the projection mirrors the image: faces that point towards the eye come out
    clockwise in NDC. Perspective: the cofactor c_w = det of the x, y, w rows' 3×3 part is
    > 0 (it is < 0 for look_at + perspective). Orthographic: the viewing direction points
    towards decreasing depth. Cone culling is disabled for such projections.

    Raises:
        ValueError: as `eye_from_view_proj`.
    """
    return eye_and_flip(check_view_proj(view_proj))[1]


# -- single-level classification --------------------------------------------------------

def classify_spheres(planes: npt.ArrayLike, centers: npt.ArrayLike, radii: npt.ArrayLike,
                     mask: npt.ArrayLike | None = None, *, scales: npt.ArrayLike | None = None,
                     inside_margin: float = DEFAULT_MARGIN,
                     outside_margin: float = DEFAULT_MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """Classify K spheres against 6 planes.

    Args:
        planes: (6, 4) plane rows, >= 0 inside (e.g. `frustum_planes`).
        centers: (K, 3); radii: (K,) >= 0.
        mask: uint8 scalar or (K,): bit k set = test plane k (default all 63); a clear bit
            means the sphere is already known to be inside plane k.
        scales: (6, 4) margin scales (default ``abs(planes)``; `frustum_plane_scales` gives
            the renderer's float32 scales).
        inside_margin, outside_margin: relative margins (see the module docstring). With
            both 0 the test is exact: INSIDE iff the closed sphere is inside every tested
            plane, OUTSIDE iff it is strictly outside one.

    Returns:
        (state uint8 (K,) of `Visibility` values, mask uint8 (K,)): the input mask with the
        bits of the planes the sphere is inside (by the margin) cleared. A sphere is OUTSIDE
        if it is outside some tested plane, INSIDE if no bit remains, else INTERSECTING.
        NaN inputs are INTERSECTING.
    """
    p, s = check_planes(planes, scales, batch=False)
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(radii, dtype=np.float64).reshape(-1)
    if r.shape[0] != c.shape[0]:
        raise ValueError(f"radii must have shape ({c.shape[0]},) to match centers, got "
                         f"{np.shape(radii)}")
    if np.any(r < 0):
        raise ValueError("radii must be >= 0")
    m = check_mask(mask, c.shape[0])
    with np.errstate(invalid="ignore", over="ignore"):
        return classify_extremes(*sphere_extremes(p, s, c, r), m, inside_margin, outside_margin)


def classify_aabbs(planes: npt.ArrayLike, mins: npt.ArrayLike, maxs: npt.ArrayLike,
                   mask: npt.ArrayLike | None = None, *, scales: npt.ArrayLike | None = None,
                   mags: npt.ArrayLike | None = None, inside_margin: float = DEFAULT_MARGIN,
                   outside_margin: float = DEFAULT_MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """Classify K axis-aligned boxes against 6 planes (n-vertex / p-vertex test).

    Same arguments and results as `classify_spheres`, with boxes ``[mins[k], maxs[k]]``
    (K, 3) and optional margin magnitudes `mags` (K, 3) (default ``max(|mins|, |maxs|)``).
    Infinite bounds are clipped to ±1e300 (so an infinite box is never culled).
    """
    p, s = check_planes(planes, scales, batch=False)
    lo, hi = check_boxes(mins, maxs)
    lo = np.clip(lo, -1e300, 1e300)
    hi = np.clip(hi, -1e300, 1e300)
    mag = box_magnitudes(lo, hi) if mags is None else np.asarray(mags, np.float64)
    m = check_mask(mask, lo.shape[0])
    with np.errstate(invalid="ignore", over="ignore"):
        return classify_extremes(*box_extremes(p, s, lo.T, hi.T, mag.T), m, inside_margin,
                       outside_margin)
