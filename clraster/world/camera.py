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
* Cameras made from pixel intrinsics (:meth:`Camera.from_intrinsics`, the trimesh and
  pyrender adapters) are tied to the image size they were made for: their projection
  refuses any other size (a K matrix is in pixels of one image).
* Vision cameras (OpenCV, COLMAP, most RGB-D datasets) look down +Z with +Y down; their
  intrinsics K put pixel (u, v)'s centre at image coordinate (u, v) (``cv2.projectPoints``).
  :meth:`Camera.from_intrinsics` derives the OpenGL-style projection that puts every point
  on the same pixel; :meth:`Camera.to_intrinsics` goes back.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from ..base.checks import check_mat4, check_size

__all__ = ["Camera", "CameraArgumentError", "intrinsics_projection", "look_at_matrix",
           "perspective_matrix", "projection_fault"]

#: |sin| of the angle between `up` and the view direction below which they count as parallel.
_PARALLEL_SIN = 1e-6
#: Condition number above which a view matrix counts as non-invertible.
_MAX_COND = 1e12
#: OpenCV camera axes (x right, y down, z forward) → OpenGL camera axes (x right, y up,
#: looking down −z), and back: the same matrix, its own inverse.
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])
#: Camera-frame conventions of a pose (camera → world) accepted by the intrinsics cameras.
CONVENTIONS = ("opencv", "opengl")
#: Condition number from which a projection counts as singular (float64's 1/eps is 4.5e15):
#: the bound `clraster.views` has always applied to a camera file's projection matrices.
_MAX_PROJ_COND = 1e15
_F32_MAX = float(np.finfo(np.float32).max)
#: Smallest normal float32: device code may flush anything below it to zero.
_F32_TINY = float(np.finfo(np.float32).tiny)


class CameraArgumentError(ValueError):
    """A camera constructor's argument is wrong: ``argument`` names it (``"eye"``,
    ``"fx"``, ``"near"``, ...), so that a camera list file can blame the entry's field of
    that name. A ValueError like every other camera error."""

    def __init__(self, argument: str, message: str) -> None:
        self.argument = argument
        super().__init__(message)

    def __reduce__(self):
        # pickle by both fields (the default would call __init__ with the message alone)
        return (type(self), (self.argument, str(self)))


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


def _unit_free_cond(p: np.ndarray) -> float:
    """Condition number of the projection `p` up to a change of units: eye-space units
    scale its translation column against the other three (P·diag(1, 1, 1, k) images the
    same scene in units k times larger), so that column is scaled to the size of the
    others first. A camera whose near plane is 1e-20 or 1e16 units away is as well
    conditioned as one at 0.1."""
    top = float(np.abs(p).max())
    if top == 0.0:
        return math.inf
    q = p / top
    c3, c012 = float(np.abs(q[:, 3]).max()), float(np.abs(q[:, :3]).max())
    if c3 > 0.0 and c012 > 0.0:
        q[:, 3] *= c012 / c3
    if np.linalg.det(q) == 0.0:
        return math.inf
    return float(np.linalg.cond(q))


def projection_fault(proj: np.ndarray) -> str | None:
    """Why the eye → clip matrix `proj` ((4, 4) float64) cannot make an image, or None.

    A fault is: a non-finite entry; an entry beyond float32's range (the renderer draws in
    float32); a matrix that is singular (condition number ≥ 1e15, up to a change of units)
    in float64, or in float32 once entries below float32's smallest normal number
    (1.2e-38) are flushed to zero as device code may do. A singular projection maps space
    onto a plane or a line (or rounding decides the image): the frame would be blank or
    garbage. The text completes "the projection ...", e.g. "is singular (...)".
    """
    if not np.all(np.isfinite(proj)):
        return "is not finite: a value overflows float64"
    if np.any(np.abs(proj) > _F32_MAX):
        return ("overflows float32, the precision the renderer draws in (entries must stay "
                "below 3.4e38)")
    p32 = proj.astype(np.float32).astype(np.float64)
    p32[np.abs(p32) < _F32_TINY] = 0.0
    for p, where in ((proj, ""), (p32, " in float32, the precision the renderer draws in, "
                                       "where entries below 1.2e-38 flush to zero")):
        cond = _unit_free_cond(p)
        if not cond < _MAX_PROJ_COND:
            return (f"is singular{where} (not invertible: condition number {cond:.3g} up to "
                    f"a change of units; it must be below 1e15): it maps space onto a plane "
                    f"or a line, or rounding decides the image")
    return None


def _refuse_degenerate(proj: np.ndarray, who: str, values: str,
                       params: Sequence[tuple[str, tuple[int, int], bool]]) -> None:
    """CameraArgumentError if `projection_fault` finds one, blaming a parameter.

    `params`: (name, the projection entry it sets, whether that entry is a scale). The
    culprit is the parameter whose entry is non-finite, else the most extreme one: a scale
    (a focal length, the depth row's) farthest from 1 by orders of magnitude (0 is
    infinitely far), an offset (principal point, skew) only if it is large (a centred
    principal point legitimately gives 0).
    """
    fault = projection_fault(proj)
    if fault is None:
        return

    def extremity(param: tuple[str, tuple[int, int], bool]) -> float:
        v = abs(float(proj[param[1]]))
        if not math.isfinite(v) or (param[2] and v == 0.0):
            return math.inf
        if v == 0.0:
            return 0.0
        mag = math.log10(v)
        return abs(mag) if param[2] else max(mag, 0.0)

    name, (i, j), _ = max(params, key=extremity)
    raise CameraArgumentError(name, f"{who}: the projection of {values} {fault}; its most "
                                    f"extreme entry is P[{i}, {j}] = {proj[i, j]:.3g}, set "
                                    f"by {name}: use a less extreme {name}")


def _check_lens_range(fov_y: float, near: float, far: float, aspect: float | None = None,
                      who: str = "look_at", values: str | None = None) -> None:
    """`_refuse_degenerate` for a perspective lens (checked floats) at `aspect`. None: a
    look_at camera, whose projection changes with the image: checked at aspect 1 (the
    field of view and the depth range are what can break). `values`: the lens as the
    message shows it (default fov_y, aspect, near, far)."""
    if values is None:
        values = (f"fov_y={fov_y}, near={near}, far={far} (at aspect 1)" if aspect is None
                  else f"fov_y={fov_y}, aspect={aspect}, near={near}, far={far}")
    _refuse_degenerate(_perspective(fov_y, 1.0 if aspect is None else aspect, near, far), who,
                       values, [("fov_y", (1, 1), True), ("aspect", (0, 0), True),
                                ("far", (2, 2), True), ("near", (2, 3), True)])


def _direction(v: np.ndarray) -> np.ndarray:
    """The unit vector along a finite non-zero `v`, whatever its length."""
    v = v / np.abs(v).max()
    return v / np.linalg.norm(v)


def look_at_matrix(eye: npt.ArrayLike, target: npt.ArrayLike,
                   up: npt.ArrayLike) -> np.ndarray:
    """World → eye matrix as gluLookAt builds it: (4, 4) float64.

    The eye maps to the origin, ``target − eye`` to −Z, and `up` (projected onto the plane
    orthogonal to the view direction) to +Y; +X = forward × up is right. Only the
    directions of ``target − eye`` and `up` matter: their lengths may be anything float64
    holds, 1e-320 or 1e300.

    Raises:
        ValueError: non-finite or wrong-shaped inputs, ``eye == target``, `up` zero or
            parallel to the view direction. `CameraArgumentError` (a ValueError) naming
            ``"eye"`` or ``"target"`` where finite inputs overflow float64: ``target − eye``
            (the one farther from the origin is named) or the translation ``−R·eye`` (eye).
    """
    eye = _vec3(eye, "eye")
    target = _vec3(target, "target")
    up = _vec3(up, "up")
    if np.array_equal(eye, target):   # (IEEE subtraction of distinct floats is never 0)
        raise CameraArgumentError("target", f"eye and target must differ (both are "
                                            f"{eye.tolist()}): the view direction is "
                                            f"target − eye")
    with np.errstate(over="ignore"):
        fwd = target - eye
    if not np.all(np.isfinite(fwd)):
        name = "target" if np.abs(target).max() > np.abs(eye).max() else "eye"
        raise CameraArgumentError(name, f"{name} overflows: target − eye, from eye "
                                        f"{eye.tolist()} to target {target.tolist()}, exceeds "
                                        f"float64's range (1.8e308); bring {name} closer to "
                                        f"the origin")
    # Only the directions of fwd and up matter: each is scaled to a largest component of 1
    # before it is normalised, so that its length (1e300 or 1e-320, or 1e200 for up) is not
    # squared into an overflow or underflow and taken for an infinite or a zero vector.
    fwd = _direction(fwd)
    up_max = float(np.abs(up).max())
    if up_max == 0.0:
        raise CameraArgumentError("up", "up must be a non-zero vector, e.g. (0, 1, 0)")
    up_dir = _direction(up)
    side = np.cross(fwd, up_dir)
    side_len = float(np.linalg.norm(side))
    if side_len < _PARALLEL_SIN:
        raise CameraArgumentError("up", f"up {up.tolist()} is parallel to the view direction "
                                        f"{fwd.tolist()}; choose an up vector that is not")
    side /= side_len
    true_up = np.cross(side, fwd)
    view = np.eye(4)
    view[0, :3] = side
    view[1, :3] = true_up
    view[2, :3] = -fwd
    with np.errstate(over="ignore", invalid="ignore"):
        view[:3, 3] = -view[:3, :3] @ eye
    if not np.all(np.isfinite(view)):
        raise CameraArgumentError("eye", f"eye {eye.tolist()} overflows: the view matrix's "
                                         f"translation −R·eye exceeds float64's range "
                                         f"(1.8e308); move the scene's origin near the camera")
    return view


def perspective_matrix(fov_y: float, aspect: float, near: float, far: float) -> np.ndarray:
    """Eye → clip matrix as gluPerspective builds it: (4, 4) float64.

    Args:
        fov_y: vertical field of view in degrees, in (0, 180).
        aspect: width / height of the viewport, > 0.
        near, far: distances to the clip planes, 0 < near < far. Eye-space z = −near maps
            to NDC z = −1, z = −far to +1.

    Raises:
        ValueError: an argument out of its range or not finite. `CameraArgumentError`
            (``argument`` naming fov_y, aspect, near or far) where the matrix is one
            `projection_fault` refuses (not invertible in float64 or float32, e.g. fov_y =
            1e-20).
    """
    fov_y, near, far = _check_lens(fov_y, near, far)
    aspect = float(aspect)
    if not (math.isfinite(aspect) and aspect > 0.0):
        raise ValueError(f"aspect must be finite and > 0, got {aspect}")
    _check_lens_range(fov_y, near, far, aspect, "perspective_matrix")
    return _perspective(fov_y, aspect, near, far)


def _perspective(fov_y: float, aspect: float, near: float, far: float) -> np.ndarray:
    """`perspective_matrix` of already checked floats: a look_at camera's, every frame
    (its lens was checked when it was made; the checks cost more than the matrix)."""
    t = math.tan(math.radians(fov_y) / 2.0)
    f = 1.0 / t if t > 0.0 else math.inf   # tan = 0 below fov_y ~3e-322°: refused there
    return np.array([[f / aspect, 0.0, 0.0, 0.0], [0.0, f, 0.0, 0.0],
                     [0.0, 0.0, (far + near) / (near - far), 2.0 * far * near / (near - far)],
                     [0.0, 0.0, -1.0, 0.0]])

def _check_near_far(near: float, far: float) -> tuple[float, float]:
    """near/far as floats with 0 < near < far, both finite."""
    _, near, far = _check_lens(90.0, near, far)
    return near, far


def _check_K(K: npt.ArrayLike) -> np.ndarray:
    """A 3×3 pinhole intrinsics matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` as a float64
    copy, or ValueError saying which entry is wrong."""
    k = _real_array(K, "K", "a 3×3 intrinsics matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    if k.shape != (3, 3):
        raise ValueError(f"K must have shape (3, 3) (a pinhole intrinsics matrix "
                         f"[[fx, s, cx], [0, fy, cy], [0, 0, 1]]), got shape {k.shape}; a 4×4 "
                         f"projection goes to Camera.from_matrices")
    if not np.all(np.isfinite(k)):
        raise ValueError("K must be finite; it contains NaN or Inf")
    if k[1, 0] != 0.0 or k[2, 0] != 0.0 or k[2, 1] != 0.0 or k[2, 2] != 1.0:
        raise ValueError(f"K must be upper triangular with K[2, 2] = 1 "
                         f"([[fx, s, cx], [0, fy, cy], [0, 0, 1]]), got {k.tolist()}")
    if not (k[0, 0] > 0.0 and k[1, 1] > 0.0):
        raise ValueError(f"K's focal lengths fx = K[0, 0] and fy = K[1, 1] must be > 0 "
                         f"(pixels), got fx={k[0, 0]}, fy={k[1, 1]}")
    return k


def intrinsics_projection(K: npt.ArrayLike, width: int, height: int, near: float,
                          far: float) -> np.ndarray:
    """Eye → clip matrix (OpenGL eye space) of an OpenCV pinhole camera: (4, 4) float64.

    Args:
        K: ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels, OpenCV's meaning: a point
            (x, y, z) in OpenCV camera coordinates (+x right, +y down, +z forward) lands at
            image coordinates ``u = (fx·x + s·y)/z + cx``, ``v = fy·y/z + cy``, and pixel
            (column i, row j) has its centre at (u, v) = (i, j) (as ``cv2.projectPoints``).
        width, height: the image K belongs to.
        near, far: clip-plane distances along the optical axis, 0 < near < far.

    Raises:
        ValueError: a bad K (`Camera.from_intrinsics`), size, near or far.
            `CameraArgumentError` (``argument`` naming fx, fy, near, far, skew, cx or cy)
            where the matrix is one `projection_fault` refuses: not invertible in float64
            or float32 (fx = 5e-324 gives P[0, 0] = 0 and a blank frame) or beyond float32.

    Derivation. clraster samples pixel (i, j) (row 0 on top) at window coordinates
    (i + 0.5, j + 0.5), with ``x_w = (x_ndc + 1)·W/2`` and ``y_w = (1 − y_ndc)·H/2``. So
    the point seen at image coordinates (u, v) must reach ``x_w = u + 0.5``,
    ``y_w = v + 0.5``, i.e.::

        x_ndc = 2(u + 0.5)/W − 1        y_ndc = 1 − 2(v + 0.5)/H

    OpenGL eye coordinates are OpenCV's with y and z negated: ``(x_e, y_e, z_e) =
    (x, −y, −z)``, and the clip w is ``−z_e = z``. Multiplying by w = z::

        x_c = x_ndc·z = (2/W)(fx·x + s·y + (cx + 0.5)·z) − z
            = (2fx/W)·x_e − (2s/W)·y_e + (1 − 2(cx + 0.5)/W)·z_e
        y_c = y_ndc·z = z − (2/H)(fy·y + (cy + 0.5)·z)
            = (2fy/H)·y_e + (2(cy + 0.5)/H − 1)·z_e

    which gives the first two rows; rows 3 and 4 are gluPerspective's (z_e = −near → NDC
    −1, z_e = −far → +1; w = −z_e)::

        [ 2fx/W   −2s/W   1 − 2(cx + 0.5)/W     0          ]
        [ 0        2fy/H  2(cy + 0.5)/H − 1     0          ]
        [ 0        0      (f + n)/(n − f)       2fn/(n − f) ]
        [ 0        0      −1                    0          ]

    A centred principal point, cx = (W − 1)/2 and cy = (H − 1)/2, gives zeros in column 3
    (a symmetric frustum): the half-pixel terms are exactly the difference between
    OpenCV's pixel centres at integers and OpenGL's at half-integers.
    """
    k = _check_K(K)
    width, height = check_size(width, height)
    near, far = _check_near_far(near, far)
    fx, s, cx = k[0]
    fy, cy = k[1, 1], k[1, 2]
    proj = np.zeros((4, 4))
    with np.errstate(over="ignore"):   # an fx of 1e308 overflows: refused just below
        proj[0, 0] = 2.0 * fx / width
        proj[0, 1] = -2.0 * s / width
        proj[0, 2] = 1.0 - 2.0 * (cx + 0.5) / width
        proj[1, 1] = 2.0 * fy / height
        proj[1, 2] = 2.0 * (cy + 0.5) / height - 1.0
    proj[2, 2] = (far + near) / (near - far)
    proj[2, 3] = 2.0 * far * near / (near - far)
    proj[3, 2] = -1.0
    _refuse_degenerate(proj, "intrinsics", f"fx={fx}, fy={fy}, s={s}, cx={cx}, cy={cy}, "
                                           f"near={near}, far={far} ({width}×{height})",
                       [("fx", (0, 0), True), ("fy", (1, 1), True), ("far", (2, 2), True),
                        ("near", (2, 3), True), ("skew", (0, 1), False),
                        ("cx", (0, 2), False), ("cy", (1, 2), False)])
    return proj


def _check_pose(pose: npt.ArrayLike | None, convention: str) -> np.ndarray:
    """A camera → world pose in `convention` as the OpenGL-frame pose (4, 4) float64."""
    if convention not in CONVENTIONS:
        raise ValueError(f"convention must be one of {list(CONVENTIONS)} (the camera frame of "
                         f"the pose: 'opencv' looks down +z with y down, 'opengl' down −z "
                         f"with y up), got {convention!r}")
    p = np.eye(4) if pose is None else check_mat4(pose, "pose")
    if not np.all(p[3] == (0.0, 0.0, 0.0, 1.0)):
        raise ValueError(f"pose must be an affine camera → world matrix (last row 0 0 0 1), "
                         f"got last row {p[3].tolist()}")
    return p @ _CV_TO_GL if convention == "opencv" else p


def _view_from_pose(pose_gl: np.ndarray) -> np.ndarray:
    """World → eye matrix from an affine camera → world pose (OpenGL camera frame)."""
    try:
        lin_inv = np.linalg.inv(pose_gl[:3, :3])
    except np.linalg.LinAlgError:
        raise ValueError("pose is singular: it must be a camera → world rigid transform "
                         "(rotation and translation)") from None
    view = np.eye(4)
    view[:3, :3] = lin_inv
    view[:3, 3] = -lin_inv @ pose_gl[:3, 3]
    return view


class Camera:
    """A pinhole camera: a view matrix plus either lens parameters or a fixed projection.

    Build one with :meth:`look_at`, :meth:`framing`, :meth:`from_matrices`,
    :meth:`from_intrinsics`, :meth:`from_trimesh` or :meth:`from_pyrender`; the
    constructor is not public API. Cameras are immutable; their matrices are read-only.
    See the module docstring for the conventions.
    """

    __slots__ = ("_view", "_projection", "_eye", "_fov_y", "_near", "_far", "_size",
                 "_origin")

    def __init__(self, view: np.ndarray, *, projection: np.ndarray | None = None,
                 lens: tuple[float, float, float] | None = None,
                 size: tuple[int, int] | None = None, origin: str = "from_matrices") -> None:
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
        # (width, height) a pixel-intrinsics camera belongs to; None: any size
        self._size = None if size is None else check_size(*size)
        self._origin = origin   # the constructor's name, for repr

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
                ``near <= 0`` or ``far <= near``. `CameraArgumentError` (a ValueError,
                ``argument`` naming the culprit) where finite inputs overflow: ``target −
                eye`` beyond float64 (eye or target), the view's translation −R·eye beyond
                float32, the renderer's precision (eye), or a lens whose projection (at
                aspect 1) `projection_fault` refuses: fov_y, near or far so extreme that it
                is not invertible in float64 or float32 (e.g. fov_y = 1e-20).
        """
        lens = _check_lens(fov_y, near, far)
        _check_lens_range(*lens)
        view = look_at_matrix(eye, target, up)
        if np.any(np.abs(view) > _F32_MAX):   # only the translation −R·eye can be large
            dist = math.hypot(*view[:3, 3].tolist())
            raise CameraArgumentError("eye", f"eye {np.asarray(eye).tolist()} is {dist:.3g} "
                                             f"from the origin: the view matrix's translation "
                                             f"overflows float32, the precision the renderer "
                                             f"draws in (3.4e38); move the scene's origin "
                                             f"near the camera")
        return cls(view, lens=lens)

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
        return cls(view, projection=projection)  # type: ignore[arg-type]  # checked there

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
        # (before dividing by tan(fov_y/2) below; the depth range is checked by look_at)
        _check_lens_range(fov_y, 1.0, 2.0, None, "framing", f"fov_y={fov_y}")
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

    @classmethod
    def from_intrinsics(cls, K: npt.ArrayLike, width: int, height: int, *,
                        pose: npt.ArrayLike | None = None, near: float, far: float,
                        convention: str = "opencv") -> Camera:
        """A pinhole camera from a vision-style intrinsics matrix and a camera → world pose.

        Args:
            K: (3, 3) ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels, OpenCV's meaning
                whatever `convention` says: u grows to the right, v downwards from the top
                row, and pixel (column i, row j) has its centre at (u, v) = (i, j), as
                ``cv2.projectPoints`` gives it. Skew s, an off-centre principal point and
                fx ≠ fy (non-square pixels) are all honoured.
            width, height: the image K belongs to. The camera is tied to it:
                :meth:`projection` refuses any other size (scale K yourself for another
                resolution: fx, fy, s by the factor, cx + 0.5 and cy + 0.5 likewise).
            pose: (4, 4) affine camera → world matrix (identity if None: the camera at the
                origin), whose camera frame is given by `convention`.
            near, far: clip-plane distances along the optical axis, 0 < near < far
                (keyword-only: there is no sensible default for a metric scene).
            convention: the camera frame of `pose`. ``"opencv"``: +x right, +y down, +z
                forward (OpenCV, COLMAP, Open3D extrinsics inverted). ``"opengl"``: +x
                right, +y up, looking down −z (OpenGL, trimesh, pyrender, Blender).

        The projection matrix is `intrinsics_projection` (its docstring has the
        derivation); the view is the inverse of the pose, turned to OpenGL axes.

        Raises:
            ValueError: K not a (3, 3) upper-triangular matrix with K[2, 2] = 1 and fx, fy
                > 0; a bad size, near/far, pose (not 4×4, not affine, singular) or
                convention; intrinsics whose projection is not invertible in float64 or
                float32 (`intrinsics_projection`: a `CameraArgumentError` naming the
                parameter).
        """
        proj = intrinsics_projection(K, width, height, near, far)
        pose_gl = _check_pose(pose, convention)
        return cls(_view_from_pose(pose_gl), projection=proj, size=(width, height),
                   origin="from_intrinsics")

    def to_intrinsics(self, width: int, height: int, *, convention: str = "opencv"
                      ) -> tuple[np.ndarray, np.ndarray]:
        """``(K, pose)`` of this camera for a ``width × height`` image: the inverse of
        :meth:`from_intrinsics`.

        Returns:
            K: (3, 3) float64 ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``, OpenCV's pixel
                convention (centres at integer coordinates).
            pose: (4, 4) float64 camera → world in `convention`'s camera frame.

        Raises:
            ValueError: the projection is not a pinhole perspective one that a K can hold
                (orthographic, an oblique near plane, a sheared or shifted clip z, a
                vertical shear), the view is not affine, or (for an intrinsics camera) the
                size differs from the camera's.
        """
        width, height = check_size(width, height)
        if convention not in CONVENTIONS:
            raise ValueError(f"convention must be one of {list(CONVENTIONS)}, got "
                             f"{convention!r}")
        p = np.array(self.projection(width, height), dtype=np.float64)
        scale = float(np.abs(p).max())
        tol = 1e-12 * scale

        def small(v) -> bool:
            return bool(np.all(np.abs(v) <= tol))

        if not (small(p[3, :2]) and small(p[3, 3]) and p[3, 2] < 0.0):
            raise ValueError("to_intrinsics needs a pinhole perspective camera (clip w = "
                             "−z_eye); this projection is orthographic or not a pinhole")
        p /= -p[3, 2]
        if not (small(p[2, :2]) and small(p[:2, 3]) and small(p[1, 0])):
            raise ValueError("to_intrinsics: this projection cannot be written as a K matrix "
                             "(an oblique near plane, a shifted image plane or a vertical "
                             "shear)")
        k = np.eye(3)
        k[0, 0] = p[0, 0] * width / 2.0
        k[0, 1] = -p[0, 1] * width / 2.0
        k[0, 2] = (1.0 - p[0, 2]) * width / 2.0 - 0.5
        k[1, 1] = p[1, 1] * height / 2.0
        k[1, 2] = (p[1, 2] + 1.0) * height / 2.0 - 0.5
        if not (k[0, 0] > 0.0 and k[1, 1] > 0.0):
            raise ValueError("to_intrinsics: this projection mirrors the image (fx or fy "
                             "would be negative)")
        view = self._view
        if not np.all(view[3] == (0.0, 0.0, 0.0, 1.0)):
            raise ValueError("to_intrinsics needs an affine view matrix (last row 0 0 0 1)")
        pose = np.eye(4)
        pose[:3, :3] = np.linalg.inv(view[:3, :3])
        pose[:3, 3] = self._eye
        if convention == "opencv":
            pose = pose @ _CV_TO_GL
        return k, pose

    @classmethod
    def from_trimesh(cls, camera, width: int | None = None, height: int | None = None, *,
                     pose: npt.ArrayLike | None = None, near: float | None = None,
                     far: float | None = None) -> Camera:
        """A camera from a ``trimesh.Scene`` (its ``camera`` placed by its
        ``camera_transform``) or a ``trimesh.scene.Camera`` (placed by `pose`).

        trimesh cameras look down −Z with +Y up (OpenGL axes); their field of view
        ``camera.fov = (fov_x, fov_y)`` in degrees spans the image edges, so a pixel centre
        sits where ``scene.camera_rays()`` casts its ray (trimesh numbers its pixel rows
        bottom-up; clraster's row 0 is the top row).

        Args:
            camera: a ``trimesh.Scene`` or a ``trimesh.scene.Camera``.
            width, height: image size; default ``camera.resolution`` (width, height).
                Another aspect ratio than the field of view's stretches the pixels.
            pose: (4, 4) camera → world (OpenGL axes) for a bare Camera; default the
                scene's ``camera_transform``, or identity for a bare Camera.
            near, far: clip planes; default the camera's ``z_near`` and ``z_far``.

        The camera is tied to ``width × height``.
        """
        tcam = camera
        scene_pose = None
        if hasattr(camera, "camera_transform") and hasattr(camera, "camera"):
            tcam = camera.camera
            scene_pose = np.asarray(camera.camera_transform, dtype=np.float64)
        if not hasattr(tcam, "fov"):
            raise ValueError(f"from_trimesh expects a trimesh.Scene or trimesh.scene.Camera, "
                             f"got {type(camera).__name__}")
        if width is None or height is None:
            res = np.asarray(tcam.resolution)
            width = int(res[0]) if width is None else width
            height = int(res[1]) if height is None else height
        width, height = check_size(width, height)
        fov = np.asarray(tcam.fov, dtype=np.float64)
        if fov.shape != (2,) or not np.all((fov > 0.0) & (fov < 180.0)):
            raise ValueError(f"trimesh camera fov must be (fov_x, fov_y) in (0, 180) degrees, "
                             f"got {fov.tolist()}")
        near = float(tcam.z_near) if near is None else near
        far = float(tcam.z_far) if far is None else far
        near, far = _check_near_far(near, far)
        proj = perspective_matrix(float(fov[1]), 1.0, near, far)
        t = math.tan(math.radians(float(fov[0])) / 2.0)
        proj[0, 0] = 1.0 / t if t > 0.0 else math.inf   # refused just below
        _refuse_degenerate(proj, "from_trimesh", f"fov={fov.tolist()}, z_near={near}, "
                                                 f"z_far={far}",
                           [("fov_x", (0, 0), True), ("fov_y", (1, 1), True),
                            ("far", (2, 2), True), ("near", (2, 3), True)])
        if pose is None:
            pose = scene_pose
        pose_gl = _check_pose(pose, "opengl")
        return cls(_view_from_pose(pose_gl), projection=proj, size=(width, height),
                   origin="from_trimesh")

    @classmethod
    def from_pyrender(cls, camera, pose: npt.ArrayLike, width: int, height: int) -> Camera:
        """A camera from a pyrender camera and its node pose, with pyrender's own projection.

        Duck-typed on pyrender's documented attributes (pyrender itself is not needed):

        * ``IntrinsicsCamera``: ``fx, fy, cx, cy, znear, zfar``, fx, fy > 0 (pixels).
          pyrender's matrix has no half-pixel shift (its cx, cy are measured from the
          image's corner, so a centred camera has cx = W/2); this reproduces pyrender's
          image. The same numbers in :meth:`from_intrinsics` (OpenCV's convention) land
          half a pixel away.
        * ``PerspectiveCamera``: ``yfov`` (radians, in (0, π)), ``znear``, ``zfar``,
          ``aspectRatio`` (> 0; None: ``width / height``).
        * ``OrthographicCamera``: ``xmag, ymag, znear, zfar`` (xmag, ymag > 0, half the
          view's width and height in world units). As pyrender's renderer does (it passes
          the viewport to ``get_projection_matrix``, which then replaces xmag by
          ``width / height · ymag``), xmag is ignored: the view is ymag high and square
          pixels give its width. An xmag(1), ymag(1) camera at 640×480 has P[0, 0] = 0.75.

        ``znear`` > 0; ``zfar`` > znear, or None for pyrender's infinite far plane (kept:
        nothing is far-clipped; an OrthographicCamera needs a finite one).

        Args:
            camera: the pyrender camera (or any object with those attributes).
            pose: (4, 4) camera → world of the camera's node, OpenGL axes (pyrender's).
            width, height: the viewport; the camera is tied to it.

        Raises:
            ValueError: not a pyrender camera; `CameraArgumentError` (a ValueError,
                ``argument`` naming the attribute) for an attribute that is not a finite
                number in its range, or that makes a projection `projection_fault` refuses
                (not invertible in float64 or float32; e.g. fx = 5e-324); a bad pose.
        """
        width, height = check_size(width, height)
        kind = type(camera).__name__
        if not (hasattr(camera, "znear") and hasattr(camera, "zfar")):
            raise ValueError(f"from_pyrender expects a pyrender camera (with znear, zfar), "
                             f"got {kind}")

        def attr(name: str) -> float:
            v = getattr(camera, name)
            try:
                f = float(v)
            except (TypeError, ValueError):
                raise CameraArgumentError(name, f"pyrender camera ({kind}) {name} must be a "
                                                f"real number, got {v!r}") from None
            if not math.isfinite(f):
                raise CameraArgumentError(name, f"pyrender camera ({kind}) {name} must be "
                                                f"finite, got {f}")
            return f

        def positive(name: str, meaning: str) -> float:
            f = attr(name)
            if not f > 0.0:
                raise CameraArgumentError(name, f"pyrender camera ({kind}) {name} is {meaning} "
                                                f"and must be > 0, got {f}")
            return f

        znear = positive("znear", "the distance to the near plane")
        zfar = None if camera.zfar is None else attr("zfar")
        if zfar is not None and not zfar > znear:
            raise CameraArgumentError("zfar", f"pyrender camera ({kind}) zfar must be > znear "
                                              f"(or None: an infinite far plane), got "
                                              f"znear={znear}, zfar={zfar}")
        proj = np.zeros((4, 4))
        # (name, entry it sets, a scale?) for _refuse_degenerate to blame
        params: list[tuple[str, tuple[int, int], bool]]
        if all(hasattr(camera, a) for a in ("fx", "fy", "cx", "cy")):
            # pyrender.IntrinsicsCamera.get_projection_matrix
            fx = positive("fx", "the focal length in pixels")
            fy = positive("fy", "the focal length in pixels")
            cx, cy = attr("cx"), attr("cy")
            values = f"fx={fx}, fy={fy}, cx={cx}, cy={cy}"
            proj[0, 0] = 2.0 * fx / width
            proj[1, 1] = 2.0 * fy / height
            proj[0, 2] = 1.0 - 2.0 * cx / width
            proj[1, 2] = 2.0 * cy / height - 1.0
            proj[3, 2] = -1.0
            params = [("fx", (0, 0), True), ("fy", (1, 1), True), ("cx", (0, 2), False),
                      ("cy", (1, 2), False)]
        elif hasattr(camera, "xmag") and hasattr(camera, "ymag"):
            # pyrender.OrthographicCamera.get_projection_matrix(width, height), as its
            # renderer calls it: xmag replaced by the viewport's aspect times ymag
            if zfar is None:
                raise CameraArgumentError("zfar", "a pyrender OrthographicCamera needs a "
                                                  "finite zfar > znear, got None")
            positive("xmag", "half the view's width (pyrender's renderer ignores it)")
            ymag = positive("ymag", "half the view's height in world units")
            values = f"ymag={ymag} (xmag ignored)"
            xmag = width / height * ymag
            # a tiny ymag may make xmag 0 and 1/xmag inf (refused below), not a
            # ZeroDivisionError
            proj[0, 0] = 1.0 / xmag if xmag > 0.0 else math.inf
            proj[1, 1] = 1.0 / ymag
            proj[2, 2] = 2.0 / (znear - zfar)
            proj[2, 3] = (zfar + znear) / (znear - zfar)
            proj[3, 3] = 1.0
            params = [("ymag", (1, 1), True), ("ymag", (0, 0), True), ("zfar", (2, 2), True)]
        elif hasattr(camera, "yfov"):
            # pyrender.PerspectiveCamera.get_projection_matrix
            yfov = attr("yfov")
            if not 0.0 < yfov < math.pi:
                hint = (f" (that is {math.degrees(yfov):.6g}°; given in degrees? pyrender's "
                        f"yfov is in radians)" if yfov >= math.pi else "")
                raise CameraArgumentError("yfov", f"pyrender camera ({kind}) yfov is the "
                                                  f"vertical field of view in radians and "
                                                  f"must be in (0, π), got {yfov}{hint}")
            if getattr(camera, "aspectRatio", None) is None:
                a = width / height
            else:
                a = positive("aspectRatio", "the field of view's width / height")
            values = f"yfov={yfov}, aspectRatio={a}"
            t = math.tan(yfov / 2.0)
            # numpy division: a tiny yfov (or a·t) may round to 0, giving inf here (refused
            # below) where Python's float division raises ZeroDivisionError
            with np.errstate(over="ignore", divide="ignore", under="ignore"):
                proj[0, 0] = np.float64(1.0) / (np.float64(a) * t)
                proj[1, 1] = np.float64(1.0) / np.float64(t)
            proj[3, 2] = -1.0
            params = [("yfov", (1, 1), True), ("aspectRatio", (0, 0), True)]
        else:
            raise ValueError(f"from_pyrender: {kind} has none of pyrender's camera "
                             f"attributes (fx/fy/cx/cy, xmag/ymag, yfov)")
        if proj[3, 2] != 0.0:   # perspective: pyrender's depth rows
            if zfar is None:
                proj[2, 2] = -1.0
                proj[2, 3] = -2.0 * znear
            else:
                proj[2, 2] = (zfar + znear) / (znear - zfar)
                proj[2, 3] = 2.0 * zfar * znear / (znear - zfar)
                params.append(("zfar", (2, 2), True))
            params.append(("znear", (2, 3), True))
        _refuse_degenerate(proj, f"from_pyrender ({kind}, {width}×{height})",
                           f"{values}, znear={znear}, zfar={zfar}", params)
        pose_gl = _check_pose(pose, "opengl")
        return cls(_view_from_pose(pose_gl), projection=proj, size=(width, height),
                   origin="from_pyrender")

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

    @property
    def image_size(self) -> tuple[int, int] | None:
        """(width, height) the camera is tied to (intrinsics cameras and adapters), else
        None (any size)."""
        return self._size

    def projection(self, width: int, height: int) -> np.ndarray:
        """Eye → clip matrix for a ``width × height`` image, (4, 4) float64.

        look_at cameras use ``aspect = width / height``; from_matrices cameras return their
        projection unchanged (a read-only array); intrinsics cameras return theirs for their
        own size only.

        Raises:
            ValueError: an intrinsics camera asked for another size than its image's.
        """
        width, height = check_size(width, height)
        if self._size is not None and (width, height) != self._size:
            w, h = self._size
            raise ValueError(f"this camera ({self._origin}) was made for a {w}×{h} image and "
                             f"its intrinsics are in that image's pixels; render at {w}×{h}, "
                             f"or build a camera for {width}×{height} (scale fx, fy, skew, "
                             f"cx + 0.5 and cy + 0.5 by the size ratio)")
        if self._projection is not None:
            return self._projection
        assert self._fov_y is not None and self._near is not None and self._far is not None
        return _perspective(self._fov_y, width / height, self._near, self._far)

    def view_projection(self, width: int, height: int) -> np.ndarray:
        """World → clip matrix ``P @ V`` for a ``width × height`` image, (4, 4) float64."""
        return self.projection(width, height) @ self._view

    def __repr__(self) -> str:
        eye = ", ".join(f"{v:.6g}" for v in self._eye)
        if self._projection is not None:
            size = "" if self._size is None else f", size={self._size[0]}x{self._size[1]}"
            return f"Camera.{self._origin}(eye=({eye}){size})"
        return (f"Camera.look_at(eye=({eye}), fov_y={self._fov_y:.6g}, "
                f"near={self._near:.6g}, far={self._far:.6g})")
