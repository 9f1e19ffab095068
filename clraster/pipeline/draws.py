"""The draws of one pass, as the vertex and setup stages read them (`FrameDraws`): plain data
over the config's record layout, shared by the frame planner (`clraster.pipeline.drawlist`), the
streamed passes, the box geometry of occlusion queries, the OpenCL stages and the NumPy
twin."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["FrameDraws", "depth_rows"]


@dataclass(frozen=True)
class FrameDraws:
    """This frame's draws. draws: DRAW_DTYPE (D,). n_verts / n_tris: sizes of the vertex and
    triangle streams. mvps: float32 (I, 16) row-major view-projection · model per instance
    (the vertex stage's: coverage). mvps64: the same float64 (I, 16) before rounding (the
    double positions of setup's value planes and clipper, kernels/setup.cl CLIP_IN).
    zrows: float64 (I, 4) per instance its w row minus its z row (the reversed-Z depth
    numerator w − z, setup.cl ClipIn).
    uplanes: float64 (I, K, 4) the frame's K user clip planes moved to each instance's
    object space (world plane · model, so distances are evaluated from object-space
    positions: common.h user_dist); K = 0 without clip planes. uclip: bit k set when plane k
    clips triangles; the others (a polygon window's bounding planes) only reject triangles
    and cull clusters wholly outside them, so they never move coverage."""

    draws: np.ndarray
    n_verts: int
    n_tris: int
    mvps: np.ndarray
    mvps64: np.ndarray
    zrows: np.ndarray
    uplanes: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 4)))
    uclip: int = 0

    @property
    def n_user(self) -> int:
        """K, the number of user clip planes."""
        return int(self.uplanes.shape[1])


def depth_rows(m64: np.ndarray) -> np.ndarray:
    """`FrameDraws.zrows` float64 (I, 4) of the float64 matrices m64 (I, 4, 4): w row − z
    row, formed before anything is rounded (so w − z keeps its relative precision far
    away, where it is a small difference of two rows near 1)."""
    m64 = np.asarray(m64, np.float64).reshape(-1, 4, 4)
    return np.ascontiguousarray(m64[:, 3, :] - m64[:, 2, :])
