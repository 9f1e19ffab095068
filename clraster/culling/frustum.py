"""Frustum math on the host: planes of a view-projection matrix, its eye, and the
classification of spheres and boxes against six planes.

Used by the draw-list builder (:mod:`clraster.culling.cull`), the renderer (eye point) and the
tests. Everything here is float64: NumPy, and plain Python floats for the eye's 3×4 minors
(`eye_and_flip`, every frame); the box / sphere primitives it shares with the BVH live in
:mod:`clraster.culling.bvh`.

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

import math

import numpy as np
import numpy.typing as npt

from ..base.checks import check_boxes, check_mat4
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

__all__ = [
    "DEFAULT_MARGIN", "PLANE_NAMES", "Visibility", "check_view_proj", "classify_aabbs",
    "classify_spheres", "eye_and_flip", "eye_from_view_proj", "frustum_plane_scales",
    "frustum_planes", "normalize_planes", "raw_planes", "view_proj_flips",
]

PLANE_NAMES = ("left", "right", "bottom", "top", "near", "far")
#: `raw_planes`: the row ri and the sign of each plane r3 ± ri, in PLANE_NAMES order.
_PLANE_ROWS = np.array([0, 0, 1, 1, 2, 2])
_PLANE_SIGNS = np.array([[1.0], [-1.0], [1.0], [-1.0], [1.0], [-1.0]])


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
    # One gather and one add each (r3 + (±1)·ri is r3 ± ri bit for bit: the product by ±1
    # is exact), not 12 row expressions stacked: ~6 µs instead of ~20 µs a call here.
    rows = vp[_PLANE_ROWS]
    raw = vp[3] + _PLANE_SIGNS * rows
    mag = np.abs(vp[3]) + np.abs(rows)
    return raw, mag


def normalize_planes(raw: np.ndarray, mag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Divide plane rows (..., 6, 4) and their scales by the normal length. A plane with a
    zero normal (e.g. an infinitely far plane: constant sign everywhere) is divided by
    |d| instead, so its value is ±1 (or 0 if it is identically zero).

    Returns (planes, scales), float64, of the inputs' shape (..., 6, 4).
    """
    xyz = raw[..., :3]
    n = np.sqrt(np.add.reduce(xyz * xyz, axis=-1))   # np.linalg.norm's own sum, unwrapped
    if not (n > 0.0).all():   # (rare: a zero or NaN normal)
        n = np.where(n > 0.0, n, np.abs(raw[..., 3]))
        n = np.where(n > 0.0, n, 1.0)
    n = n[..., None]
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


def _cofactors(x: list[float], y: list[float], w: list[float]) -> tuple[float, ...]:
    """(c0, c1, c2, c3) with c·q = det([x; y; w; q]) for three 4-rows (Python floats): the
    null vector of x, y, w, each entry a signed 3×3 minor (cofactor expansion along q)."""
    # 2×2 minors of the y, w rows, columns (i, j)
    m01 = y[0] * w[1] - y[1] * w[0]
    m02 = y[0] * w[2] - y[2] * w[0]
    m03 = y[0] * w[3] - y[3] * w[0]
    m12 = y[1] * w[2] - y[2] * w[1]
    m13 = y[1] * w[3] - y[3] * w[1]
    m23 = y[2] * w[3] - y[3] * w[2]
    return (-(x[1] * m23 - x[2] * m13 + x[3] * m12),
            x[0] * m23 - x[2] * m03 + x[3] * m02,
            -(x[0] * m13 - x[1] * m03 + x[3] * m01),
            x[0] * m12 - x[1] * m02 + x[2] * m01)


#: `eye_and_flip` solves for its translation point in closed form (Cramer's rule: the
#: cofactors' c[:3] / c[3]) when the x, y, w rows' 3×3 part has |det| above this share of
#: the product of its row norms (a perspective camera: ~1; their sine-volume); else
#: (orthographic: w row (0, 0, 0, 1), det exactly 0; or nearly dependent rows) by
#: least squares as before. Cramer's relative error grows with the condition number, which
#: this bound keeps below ~1e6 — and the cofactor step after the translation corrects the
#: point to the eye anyway (a Newton step), so only the translation's size depends on it.
_CRAMER_MIN = 1e-6


def eye_and_flip(vp: np.ndarray) -> tuple[np.ndarray, bool]:
    """(`eye_from_view_proj`, `view_proj_flips`) of a checked float64 (4, 4) `vp` at once.

    Raises:
        ValueError: as `eye_from_view_proj`.
    """
    # Plain Python floats on the 3×4 rows (closed-form 3×3 minors): a renderer calls this
    # every frame, and the NumPy version (lstsq, four np.linalg.det, norms on 3×4 arrays)
    # cost ~20 times as much; the lstsq branch below is kept for orthographic and
    # near-singular projections.
    # Over 3,000 random cameras (eyes up to 1e9 from the origin, mirrored, orthographic,
    # random and near-dependent matrices) the eye agreed with the NumPy version's to
    # 5e-15 relative, and the flip, the branch taken and every refusal were the same.
    r = vp.tolist()
    x, y, w = r[0], r[1], r[3]
    # Move the world origin to (about) the eye first: the rows' norms grow with the camera's
    # distance from the origin, and so the degeneracy test below refused every camera
    # farther than ~1e6 units (georeferenced scenes). The least-squares point of the x, y
    # and w rows is the eye of a perspective view and a point of the view axis of an
    # orthographic one; a translation leaves the answer's meaning unchanged.
    c = _cofactors(x, y, w)
    c3 = c[3]   # det of the rows' 3×3 part: a translation leaves it unchanged
    vol = (math.hypot(x[0], x[1], x[2]) * math.hypot(y[0], y[1], y[2])
           * math.hypot(w[0], w[1], w[2]))
    if abs(c3) > _CRAMER_MIN * vol:   # the exact solution of the rows' 3×3 system
        p0 = [c[0] / c3, c[1] / c3, c[2] / c3]
    else:
        p3 = vp[[0, 1, 3]]
        p0 = np.linalg.lstsq(p3[:, :3], -p3[:, 3], rcond=None)[0].tolist()
    if not all(map(math.isfinite, p0)):
        p0 = [0.0, 0.0, 0.0]
    x0, y0, w0 = ([v[0], v[1], v[2], v[0] * p0[0] + v[1] * p0[1] + v[2] * p0[2] + v[3]]
                  for v in (x, y, w))
    c = _cofactors(x0, y0, w0)
    scale = math.hypot(*x0) * math.hypot(*y0) * math.hypot(*w0)
    cn = math.hypot(*c)
    if not cn > 1e-12 * scale:
        raise ValueError("view_proj has linearly dependent x, y and w rows: it has no eye "
                         "point or viewing direction (a degenerate projection)")
    c3 = c[3]
    if abs(c3) > 1e-12 * cn:
        return (np.array([c[0] / c3 + p0[0], c[1] / c3 + p0[1], c[2] / c3 + p0[2], 1.0]),
                c3 > 0.0)
    dn = math.hypot(c[0], c[1], c[2])
    d = [c[0] / dn, c[1] / dn, c[2] / dn]
    z = r[2]
    return np.array([*d, 0.0]), (z[0] * d[0] + z[1] * d[1] + z[2] * d[2]) < 0.0


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
