"""Shadow-map lookups, host side (kernels/shadow.cl): per pixel of a camera frame, the
fraction of one light reaching its visible point (`clraster.output.lights` gives the method;
`clraster.pipeline.reference.shadow` is the NumPy twin). `clraster.pipeline.stages.post`'s
`DevicePasses` runs it for render_shaded."""

from __future__ import annotations

import math

import numpy as np
import pyopencl as cl

from ...base.config import RasterConfig
from ...output.lights import LIGHT_SPOT, Light, ShadowMap
from ..device import kernel, program

__all__ = ["ShadowStage"]

#: Work-group shape (x, y) of the per-pixel kernel.
LOCAL = (16, 4)
MF = cl.mem_flags


class ShadowStage:
    """The ``shadow_lookup`` kernel of one context."""

    def __init__(self, ctx: cl.Context) -> None:
        self.ctx = ctx
        self.kernel = kernel(program(ctx, "shadow", RasterConfig().build_options()),
                             "shadow_lookup")

    def run(self, queue: cl.CommandQueue, smap: ShadowMap, light: Light, depth: np.ndarray,
            normals: np.ndarray, vp: np.ndarray, reversed_z: bool) -> np.ndarray:
        """float32 (H, W) lit fraction × cone factor (`clraster.output.lights.shadow_lookup`'s
        arguments and result); blocking."""
        h, w = depth.shape
        lo = hi = 1.0
        if light.kind == LIGHT_SPOT:
            lo, hi = math.cos(math.radians(light.cone)), math.cos(math.radians(light.inner))
        pos = light.position if light.position is not None else np.zeros(3)
        params = np.concatenate([np.linalg.inv(vp).ravel(), smap.view.ravel(),
                                 smap.projection.ravel(), light.direction, pos,
                                 [smap.texel, light.bias, light.slope_bias, lo, hi]])

        def buf(a: np.ndarray) -> cl.Buffer:
            return cl.Buffer(self.ctx, MF.READ_ONLY | MF.COPY_HOST_PTR,
                             hostbuf=np.ascontiguousarray(a))

        out = np.empty((h, w), np.float32)
        d_out = cl.Buffer(self.ctx, MF.WRITE_ONLY, max(out.nbytes, 4))
        gsize = (-(-w // LOCAL[0]) * LOCAL[0], -(-h // LOCAL[1]) * LOCAL[1])
        self.kernel(queue, gsize, LOCAL, buf(depth.astype(np.float32)),
                    buf(normals.astype(np.float32)), buf(smap.depth.astype(np.float32)),
                    buf(params.astype(np.float64)), d_out, np.int32(w), np.int32(h),
                    np.int32(smap.depth.shape[0]), np.int32(light.pcf),
                    np.int32(smap.perspective), np.int32(light.kind == LIGHT_SPOT),
                    np.int32(reversed_z))
        cl.enqueue_copy(queue, out, d_out, is_blocking=True)
        return out
