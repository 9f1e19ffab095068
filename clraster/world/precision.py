"""Warnings for inputs that float32 cannot render faithfully.

The pipeline is float32 from clip space on (as GPUs and llvmpipe with a 32-bit float depth
buffer are). Where an input makes the result degrade — not fail — clraster says so once per
cause with a `PrecisionWarning` (Python shows a warning once per place by default) naming
the cause and the fix, rather than returning a silently partial image.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["PrecisionWarning", "check_depth_range"]

#: The largest float32 below 1 is 1 − 2**−24; window depths from 1 − 2**−25 up round to 1.0,
#: which the LESS test against the cleared 1.0 never passes.
_LAST_DEPTH = 1.0 - 2.0**-25
#: Warn when geometry is lost over more than this share of the [eye, far plane] distance: a
#: sliver at the far plane always rounds to 1.0 (in any float32 depth buffer).
_LOST_SHARE = 0.5


class PrecisionWarning(UserWarning):
    """The image is degraded by float32 limits (e.g. a near plane far too small)."""


def depth_horizon(rows: np.ndarray | tuple[tuple[float, float], tuple[float, float]]
                  ) -> tuple[float, float]:
    """Distances along the view axis at which float32 window depth reaches 1.0 and at which
    the far plane lies: (t_horizon, t_far), float64; inf where never reached.

    Args:
        rows: float64 (2, 2) (an array, or nested pairs of floats), clip z and w along the
            axis as affine functions of the distance t from the eye: ``[[z0, z1], [w0,
            w1]]`` (z = z0 + z1·t, ...). Then
            z/w = q solves to t = (q·w0 − z0) / (z1 − q·w1).
    """
    (z0, z1), (w0, w1) = rows

    def solve(q: float) -> float:
        den = z1 - q * w1
        t = (q * w0 - z0) / den if den != 0.0 else np.inf
        return float(t) if t > 0.0 else np.inf

    return solve(2.0 * _LAST_DEPTH - 1.0), solve(1.0)


def check_depth_range(camera, width: int, height: int, scene) -> None:
    """Warn (`PrecisionWarning`) if part of ``scene`` lies where float32 window depth has
    already reached 1.0 although the far plane is much farther: such geometry is never
    drawn.

    Needs the camera's own view and projection (a `clraster.Camera`): from the product
    alone, the depth offsets that matter (2·far·near/(near − far) ≈ 2e-28 for near = 1e-30)
    drown in the rounding of the eye's translation. Other cameras are not checked.
    """
    # Every frame calls this (plan_frame); for the usual camera it returns at the first or
    # second test, so those stay on plain Python floats (NumPy's per-call overhead would be
    # most of its cost), and the scene's bounds, when needed, are kept per scene.
    try:
        view = np.asarray(camera.view, np.float64)
        proj = np.asarray(camera.projection(width, height), np.float64)
    except (AttributeError, TypeError):
        return
    if proj[3].tolist() != [0.0, 0.0, -1.0, 0.0]:
        return   # not a perspective projection: depth is linear in distance (orthographic)
    # eye space: the view axis is (0, 0, −t), so z = P22·(−t) + P23 and w = t
    p22, p23 = proj[2, 2:].tolist()
    t_h, t_far = depth_horizon(((p23, -p22), (0.0, 1.0)))
    if not t_h < _LOST_SHARE * t_far:
        return
    corners = scene.memo("precision.bound_corners", lambda: _bound_corners(scene))
    if corners is None:   # no finite geometry: nothing to lose
        return
    reach = float(-(corners @ view[2]).min())
    if reach > t_h:
        warnings.warn(
            f"window depth is float32: with this projection everything farther than "
            f"{t_h:.3g} from the eye gets depth 1.0 and is never drawn (the far plane is at "
            f"{t_far:.3g}), and the scene reaches {reach:.3g}; use a larger near plane "
            f"(depth resolution follows near/far, and float32 resolves far/near up to "
            f"~2**24) or a nearer far plane", PrecisionWarning, stacklevel=4)


def _bound_corners(scene) -> np.ndarray | None:
    """float64 (8, 4) the homogeneous corners of ``scene.bounds()``, None where it has no
    finite geometry; depends on the scene only (`check_depth_range` keeps it with the
    scene: `Scene.memo`, remade when the scene changes)."""
    try:
        lo, hi = scene.bounds()
    except ValueError:
        return None
    corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    corners.flags.writeable = False
    return corners
