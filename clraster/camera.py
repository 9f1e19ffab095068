"""Pinhole cameras with OpenGL conventions.

Conventions (the same as OpenGL, gluLookAt and gluPerspective, so trimesh/pyrender cameras
carry over unchanged):

* World space is right-handed. Eye space: the camera sits at the origin, looks down −Z,
  +X is right and +Y is up.
* Matrices are float64, 4×4, for column vectors: ``clip = P @ V @ [x, y, z, 1]``.
  ``V`` (view) maps world → eye, ``P`` (projection) maps eye → clip.
* Clip space: a point is inside the view volume iff −w ≤ x, y, z ≤ w. After the divide,
  NDC z = −1 is the near plane and +1 the far plane; window depth is ``(z/w + 1) / 2``.
* The aspect ratio of a :meth:`Camera.look_at` camera is not part of the camera: it is
  ``width / height`` of the image it renders, supplied to :meth:`Camera.view_projection`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from .inputs import check_mat4, check_size

__all__ = ["Camera", "look_at_matrix", "perspective_matrix"]

#: |sin| of the angle between `up` and the view direction below which they count as parallel.
_PARALLEL_SIN = 1e-6
#: Condition number above which a view matrix counts as non-invertible.
_MAX_COND = 1e12


def _real_array(value: npt.ArrayLike, name: str, expected: str) -> np.ndarray:
    """A float64 copy of `value` (callers' arrays are never aliased), if it is real numeric."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be {expected}, got {value!r}") from exc
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be {expected}, got dtype {arr.dtype}")
    return arr.astype(np.float64, copy=True)


def _vec3(value: npt.ArrayLike, name: str) -> np.ndarray:
    """`value` as a finite float64 (3,) array, or ValueError naming `name`."""
    arr = _real_array(value, name, "3 real numbers (x, y, z)")
    if arr.shape != (3,):
        raise ValueError(f"{name} must have shape (3,) (x, y, z), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def _check_lens(fov_y: float, near: float, far: float) -> tuple[float, float, float]:
    vals = []
    for name, v in (("fov_y", fov_y), ("near", near), ("far", far)):
        try:
            f = float(v)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a real number, got {v!r}") from exc
        if not math.isfinite(f):
            raise ValueError(f"{name} must be finite, got {f}")
        vals.append(f)
    fov_y, near, far = vals
    if not 0.0 < fov_y < 180.0:
        raise ValueError(f"fov_y is the vertical field of view in degrees and must be in "
                         f"(0, 180), got {fov_y}")
    if near <= 0.0:
        raise ValueError(f"near must be > 0 (distance to the near plane), got {near}")
    if far <= near:
        raise ValueError(f"far must be > near, got near={near}, far={far}")
    return fov_y, near, far


def look_at_matrix(eye: npt.ArrayLike, target: npt.ArrayLike,
                   up: npt.ArrayLike) -> np.ndarray:
    """World → eye matrix as gluLookAt builds it: (4, 4) float64.

    The eye maps to the origin, ``target − eye`` to −Z, and `up` (projected onto the plane
    orthogonal to the view direction) to +Y; +X = forward × up is right.

    Raises:
        ValueError: non-finite or wrong-shaped inputs, ``eye == target``, `up` zero or
            parallel to the view direction.
    """
    eye = _vec3(eye, "eye")
    target = _vec3(target, "target")
    up = _vec3(up, "up")
    fwd = target - eye
    dist = float(np.linalg.norm(fwd))
    if dist == 0.0 or not math.isfinite(dist):
        raise ValueError(f"eye and target must differ (both are {eye.tolist()}): the view "
                         f"direction is target − eye")
    fwd /= dist
    up_len = float(np.linalg.norm(up))
    if up_len == 0.0:
        raise ValueError("up must be a non-zero vector, e.g. (0, 1, 0)")
    side = np.cross(fwd, up / up_len)
    side_len = float(np.linalg.norm(side))
    if side_len < _PARALLEL_SIN:
        raise ValueError(f"up {up.tolist()} is parallel to the view direction "
                         f"{fwd.tolist()}; choose an up vector that is not")
    side /= side_len
    true_up = np.cross(side, fwd)
    view = np.eye(4)
    view[0, :3] = side
    view[1, :3] = true_up
    view[2, :3] = -fwd
    view[:3, 3] = -view[:3, :3] @ eye
    return view


def perspective_matrix(fov_y: float, aspect: float, near: float, far: float) -> np.ndarray:
    """Eye → clip matrix as gluPerspective builds it: (4, 4) float64.

    Args:
        fov_y: vertical field of view in degrees, in (0, 180).
        aspect: width / height of the viewport, > 0.
        near, far: distances to the clip planes, 0 < near < far. Eye-space z = −near maps
            to NDC z = −1, z = −far to +1.
    """
    fov_y, near, far = _check_lens(fov_y, near, far)
    aspect = float(aspect)
    if not (math.isfinite(aspect) and aspect > 0.0):
        raise ValueError(f"aspect must be finite and > 0, got {aspect}")
    f = 1.0 / math.tan(math.radians(fov_y) / 2.0)
    proj = np.zeros((4, 4))
    proj[0, 0] = f / aspect
    proj[1, 1] = f
    proj[2, 2] = (far + near) / (near - far)
    proj[2, 3] = 2.0 * far * near / (near - far)
    proj[3, 2] = -1.0
    return proj


class Camera:
    """A pinhole camera: a view matrix plus either lens parameters or a fixed projection.

    Build one with :meth:`look_at`, :meth:`framing` or :meth:`from_matrices`; the
    constructor is not public API. Cameras are immutable; their matrices are read-only.
    See the module docstring for the conventions.
    """

    __slots__ = ("_view", "_projection", "_eye", "_fov_y", "_near", "_far")

    def __init__(self, view: np.ndarray, *, projection: np.ndarray | None = None,
                 lens: tuple[float, float, float] | None = None) -> None:
        if (projection is None) == (lens is None):
            raise ValueError("Camera needs exactly one of projection or lens; use "
                             "Camera.look_at or Camera.from_matrices")
        view = check_mat4(view, "view", read_only=True)
        # An affine view (last row 0 0 0 1) is tested on its 3×3 part only: the condition
        # number of the whole 4×4 grows with the square of the translation, which refused
        # every camera ~1e6 units from the origin (georeferenced scenes) although a rigid
        # transform is perfectly conditioned wherever it is.
        affine = bool(np.all(view[3] == (0.0, 0.0, 0.0, 1.0)))
        try:
            cond = np.linalg.cond(view[:3, :3] if affine else view)
        except np.linalg.LinAlgError:
            cond = math.inf
        if not cond < _MAX_COND:
            raise ValueError("view matrix is not invertible (singular or nearly so); it must "
                             "map world to eye space, e.g. a rigid transform")
        if affine:   # the eye is where the view maps to the origin: L @ eye + t = 0
            eye = -np.linalg.solve(view[:3, :3], view[:3, 3])
        else:
            inv = np.linalg.inv(view)
            w = inv[3, 3]
            if abs(w) < 1e-12:
                raise ValueError("view matrix maps the eye to infinity (its inverse has "
                                 "w = 0 in the last column); use an affine view matrix")
            eye = inv[:3, 3] / w
        eye.flags.writeable = False
        self._view = view
        self._eye = eye
        self._projection = (None if projection is None
                            else check_mat4(projection, "projection", read_only=True))
        if lens is None:
            self._fov_y = self._near = self._far = None
        else:
            self._fov_y, self._near, self._far = _check_lens(*lens)

    # -- constructors -------------------------------------------------------------------

    @classmethod
    def look_at(cls, eye: npt.ArrayLike, target: npt.ArrayLike,
                up: npt.ArrayLike = (0.0, 1.0, 0.0), fov_y: float = 45.0,
                near: float = 0.1, far: float = 100.0) -> Camera:
        """A perspective camera at `eye` looking at `target` (gluLookAt + gluPerspective).

        Args:
            eye, target, up: world-space 3-vectors; `up` need not be orthogonal to the
                view direction but must not be parallel to it.
            fov_y: vertical field of view in degrees, in (0, 180).
            near, far: clip-plane distances along the view direction, 0 < near < far.

        The aspect ratio is taken from the image at render time (width / height).

        Raises:
            ValueError: any input non-finite or of the wrong shape, ``eye == target``,
                `up` zero or parallel to the view direction, fov_y outside (0, 180),
                ``near <= 0`` or ``far <= near``.
        """
        lens = _check_lens(fov_y, near, far)
        return cls(look_at_matrix(eye, target, up), lens=lens)

    @classmethod
    def from_matrices(cls, view: npt.ArrayLike, projection: npt.ArrayLike) -> Camera:
        """A camera from raw matrices (4×4 each, column-vector convention).

        Args:
            view: world → eye; must be invertible (the eye position comes from its inverse).
            projection: eye → clip, used unchanged whatever the image size, so it carries
                its own aspect ratio.

        Raises:
            ValueError: wrong shape, non-finite entries, or a non-invertible view.
        """
        return cls(view, projection=projection)

    @classmethod
    def framing(cls, bounds_min: npt.ArrayLike, bounds_max: npt.ArrayLike, *,
                direction: Sequence[float] | np.ndarray = (1.0, 0.6, 1.6),
                fov_y: float = 45.0, aspect: float = 1.0) -> Camera:
        """A look_at camera that sees the whole axis-aligned box ``[bounds_min, bounds_max]``.

        The camera looks at the box centre from ``centre + distance · direction/|direction|``,
        with world +Y as up (world −Z when `direction` is vertical), at the smallest
        distance at which all 8 corners lie inside the vertical field of view and the
        horizontal one implied by `aspect`, with a 5% margin. near is half the depth of
        the nearest corner and far 1.5× that of the farthest, so nothing of the box is
        clipped. A box of zero size frames a small cube around its point.

        Args:
            bounds_min, bounds_max: (3,) corners, bounds_min <= bounds_max per axis.
            direction: from the box centre towards the eye, need not be unit length.
            fov_y: vertical field of view in degrees, in (0, 180).
            aspect: width / height of the image that will be rendered (only used to fit the
                box; the rendered aspect still comes from the image size).
        """
        lo = _vec3(bounds_min, "bounds_min")
        hi = _vec3(bounds_max, "bounds_max")
        if np.any(lo > hi):
            raise ValueError(f"bounds_min {lo.tolist()} must be <= bounds_max {hi.tolist()} "
                             f"on every axis")
        d = _vec3(direction, "direction")
        d_len = float(np.linalg.norm(d))
        if d_len == 0.0:
            raise ValueError("direction must be a non-zero vector (from target towards eye)")
        d /= d_len
        fov_y, _, _ = _check_lens(fov_y, 1.0, 2.0)
        aspect = float(aspect)
        if not (math.isfinite(aspect) and aspect > 0.0):
            raise ValueError(f"aspect must be finite and > 0, got {aspect}")
        centre = (lo + hi) / 2.0
        radius = float(np.linalg.norm(hi - lo)) / 2.0
        if radius == 0.0:  # a single point: frame a small neighbourhood of it
            radius = max(1.0, float(np.abs(centre).max())) * 1e-3
            lo, hi = centre - radius, centre + radius
        up = np.array([0.0, 1.0, 0.0])
        if np.linalg.norm(np.cross(d, up)) < 1e-3:
            up = np.array([0.0, 0.0, -1.0])
        # Corners in the camera basis (x right, y up, z towards the eye, origin at the box
        # centre). With the eye at distance D, a corner is at depth D − z and inside the
        # frustum iff |x| <= (D − z)·tan(half_x) and |y| <= (D − z)·tan(half_y). The
        # frustum is convex, so containing the 8 corners contains the whole box.
        rot = look_at_matrix(centre + d, centre, up)[:3, :3]
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])]) - centre
        cx, cy, cz = (corners @ rot.T).T
        tan_y = math.tan(math.radians(fov_y) / 2.0)
        tan_x = tan_y * aspect
        margin = 1.05  # the outermost corner lands at most 1/1.05 of the way to the border
        need = cz + margin * np.maximum(np.abs(cx) / tan_x, np.abs(cy) / tan_y)
        dist = max(float(need.max()), float(cz.max()) + 0.05 * radius)
        eye = centre + dist * d
        # Depths of the corners along the view axis lie in [dist − max z, dist − min z].
        near = (dist - float(cz.max())) * 0.5
        far = (dist - float(cz.min())) * 1.5
        return cls.look_at(eye, centre, up, fov_y=fov_y, near=near, far=far)

    # -- properties ---------------------------------------------------------------------

    @property
    def view(self) -> np.ndarray:
        """World → eye matrix, (4, 4) float64, read-only."""
        return self._view

    @property
    def eye(self) -> np.ndarray:
        """Camera position in world space, (3,) float64, read-only."""
        return self._eye

    @property
    def fov_y(self) -> float | None:
        """Vertical field of view in degrees; None for a from_matrices camera."""
        return self._fov_y

    @property
    def near(self) -> float | None:
        """Near-plane distance; None for a from_matrices camera."""
        return self._near

    @property
    def far(self) -> float | None:
        """Far-plane distance; None for a from_matrices camera."""
        return self._far

    def projection(self, width: int, height: int) -> np.ndarray:
        """Eye → clip matrix for a ``width × height`` image, (4, 4) float64.

        look_at cameras use ``aspect = width / height``; from_matrices cameras return their
        projection unchanged (a read-only array).
        """
        width, height = check_size(width, height)
        if self._projection is not None:
            return self._projection
        assert self._fov_y is not None and self._near is not None and self._far is not None
        return perspective_matrix(self._fov_y, width / height, self._near, self._far)

    def view_projection(self, width: int, height: int) -> np.ndarray:
        """World → clip matrix ``P @ V`` for a ``width × height`` image, (4, 4) float64."""
        return self.projection(width, height) @ self._view

    def __repr__(self) -> str:
        eye = ", ".join(f"{v:.6g}" for v in self._eye)
        if self._projection is not None:
            return f"Camera.from_matrices(eye=({eye}))"
        return (f"Camera.look_at(eye=({eye}), fov_y={self._fov_y:.6g}, "
                f"near={self._near:.6g}, far={self._far:.6g})")
