"""Per-pixel passes on the device, host side (kernels/post.cl: SSAO and FXAA; the
shadow-map lookups of kernels/shadow.cl through `clraster.pipeline.stages.shadow`).

`DevicePasses` runs render_shaded's passes (`clraster.output.post.Passes`) for frames of an
OpenCL renderer, in its context, on a queue of its own; importing this module registers it
with `clraster.output.post.register_passes`, so render_shaded finds it for any renderer that
has an OpenCL ``context``. The NumPy twins are `clraster.output.post.ssao_inputs` /
`ssao_taps_pass` / `fxaa` and `clraster.output.lights.shadow_lookup`. Each pass is one
blocking call. Inputs and results are the caller's arrays themselves where the device works
in host memory (CL_MEM_USE_HOST_PTR on PoCL's CPU devices: no copies), copies elsewhere;
intermediate buffers (SSAO's half-resolution positions, linear depths and factor, FXAA's
luma, edge-pixel list and its count) are `GrowBuffer`s kept from frame to frame.
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np
import pyopencl as cl

from ...base.config import RasterConfig
from ...output.lights import Light, ShadowMap
from ...output.post import (
    SSAO,
    SSAO_UPSAMPLE_DEPTH,
    Passes,
    register_passes,
    rgb8,
    ssao_prepare_matrix,
    ssao_radius_scale,
    ssao_taps,
)
from ..device import kernel, program, shares_host_memory
from ._buffers import GrowBuffer
from .shadow import ShadowStage

__all__ = ["DevicePasses", "device_passes"]

#: Work-group shape of the SSAO kernels (x, y): 16 work-items of a row (LANES pixels each),
#: 4 rows.
LOCAL = (16, 4)
MF = cl.mem_flags


#: Pixels of a row per work-item of the SSAO kernels (post.cl's LANES).
LANES = 8
#: FXAA: one work-item per FXAA_SPAN pixels of a row (kernels/post.cl's FXAA_SPAN), 64 per
#: group.
FXAA_SPAN = 16
FXAA_LOCAL = (64, 1)


def _ssao_skip_bias2(bias: float) -> np.float32:
    """Kernel ``ssao``'s threshold for skipping a tap's square root and division: bias²
    less 2^-10 of it (the margin that makes a skipped lane's term exactly 0; post.cl)."""
    return np.float32(float(bias) ** 2 * (1.0 - 2.0 ** -10))


def _global(w: int, h: int) -> tuple[int, int]:
    return (-(-w // LOCAL[0]) * LOCAL[0], -(-h // LOCAL[1]) * LOCAL[1])


def _lanes_global(w: int, h: int) -> tuple[int, int]:
    """Global size of a kernel doing LANES (8) pixels of a row per work-item (post.cl)."""
    return _global(-(-w // LANES), h)


def _fxaa_global(w: int, h: int) -> tuple[int, int]:
    n = -(-w // FXAA_SPAN)
    return (-(-n // FXAA_LOCAL[0]) * FXAA_LOCAL[0], h)


class DevicePasses:
    """The passes of `clraster.output.post.Passes` in one OpenCL context."""

    def __init__(self, ctx: cl.Context) -> None:
        self.ctx = ctx
        self.queue = cl.CommandQueue(ctx)
        opts = RasterConfig().build_options()
        post = program(ctx, "post", (*opts, f"-DFXAA_SPAN={FXAA_SPAN}"))
        self.k_prepare = kernel(post, "ssao_prepare")
        self.k_ssao = kernel(post, "ssao")
        self.k_luma = kernel(post, "luma")
        self.k_mark = kernel(post, "fxaa_mark")
        self.k_edges = kernel(post, "fxaa_edges")
        self.k_upsample = kernel(post, "ssao_upsample")
        self.host = shares_host_memory(ctx)
        # reused frame to frame (grown when a frame is larger)
        self.params = GrowBuffer(ctx, MF.READ_ONLY)
        self.taps = GrowBuffer(ctx, MF.READ_ONLY)
        self.pos = GrowBuffer(ctx)
        self.zlow = GrowBuffer(ctx)
        self._taps_for = 0
        self._taps_array = np.zeros((0, 2), np.float32)
        self.ao_low = GrowBuffer(ctx)
        self.lum = GrowBuffer(ctx)
        self.edge_list = GrowBuffer(ctx)
        self.edge_count = GrowBuffer(ctx, host=True)
        self.scratch_out = GrowBuffer(ctx)
        self.shadow_stage = ShadowStage(ctx)

    def _in(self, a: np.ndarray) -> cl.Buffer:
        """A read-only buffer of `a`: over `a` itself (CL_MEM_USE_HOST_PTR, no copy) where
        the device works in host memory, else a copy. Keep `a` alive until the pass's
        wait."""
        a = np.ascontiguousarray(a)
        flag = MF.USE_HOST_PTR if self.host else MF.COPY_HOST_PTR
        return cl.Buffer(self.ctx, MF.READ_ONLY | flag, hostbuf=a)

    def _result(self, out: np.ndarray) -> tuple[cl.Buffer, bool]:
        """A write-only buffer for `out`: over `out` itself where the device works in host
        memory (True: nothing to read back after the wait), else a scratch buffer."""
        if self.host:
            return cl.Buffer(self.ctx, MF.WRITE_ONLY | MF.USE_HOST_PTR, hostbuf=out), True
        return self.scratch_out.ensure(out.nbytes, "post-pass output"), False

    def _finish(self, out: np.ndarray, buf: cl.Buffer, in_place: bool) -> np.ndarray:
        if in_place:
            self.queue.finish()
        else:
            cl.enqueue_copy(self.queue, out, buf, is_blocking=True)
        return out

    def shadow(self, smap: ShadowMap, light: Light, depth: np.ndarray, normals: np.ndarray,
               vp: np.ndarray, reversed_z: bool) -> np.ndarray:
        return self.shadow_stage.run(self.queue, smap, light, depth, normals, vp, reversed_z)

    def ssao_inputs(self, depth: cl.Buffer, vp: np.ndarray, reversed_z: bool, radius: float,
                    h: int, w: int, m: np.ndarray | None = None) -> tuple[cl.Buffer, cl.Buffer]:
        """SSAO's first pass (kernel ``ssao_prepare``) over the float32 (h, w) window depth
        `depth`: device buffers on the half-resolution (⌈h/2⌉, ⌈w/2⌉) grid, reused from
        call to call: float4 positions (xyz relative to `ssao_origin`, inf on the
        background; w the radius in low-res pixels, 0 on the background) and float linear
        depths (inf on the background) — `clraster.output.post.ssao_inputs`' positions and
        its normals' w. The normals themselves the taps kernel reads from the frame. `m`:
        `ssao_prepare_matrix(vp)` where the caller has it."""
        h2, w2 = (h + 1) // 2, (w + 1) // 2
        if m is None:
            m = ssao_prepare_matrix(vp)
        pos = self.pos.ensure(16 * w2 * h2, "SSAO position buffer")
        zlow = self.zlow.ensure(4 * w2 * h2, "SSAO linear depth buffer")
        self.k_prepare(self.queue, _lanes_global(w2, h2), LOCAL, depth, pos, zlow,
                       np.int32(w), np.int32(h), np.int32(reversed_z), m[0], m[1], m[2], m[3],
                       np.float32(2.0 / w), np.float32(2.0 / h),
                       ssao_radius_scale(vp, radius, h))
        return pos, zlow

    def ssao(self, depth: np.ndarray, normals: np.ndarray, vp: np.ndarray, reversed_z: bool,
             params: SSAO) -> np.ndarray:
        """`clraster.output.post.ssao` on the device, the same bits: kernels ``ssao_prepare``
        (positions), ``ssao`` (the taps, at half resolution) and ``ssao_upsample``, queued
        back to back with one wait; a new float32 (H, W) array."""
        assert params.radius is not None
        h, w = depth.shape
        h2, w2 = (h + 1) // 2, (w + 1) // 2
        depth = np.ascontiguousarray(depth, dtype=np.float32)
        normals = np.ascontiguousarray(normals, dtype=np.float32)
        if self._taps_for != params.samples:
            self._taps_array = ssao_taps(params.samples)
            self._taps_for = params.samples
        # the taps first: a write waits for the queue, and here it is empty
        self.taps.write(self.queue, self._taps_array)
        d_depth, d_nrm = self._in(depth), self._in(normals)
        m = ssao_prepare_matrix(vp)   # row 3: vp⁻¹'s, the upsample's too
        sx, sy = np.float32(2.0 / w), np.float32(2.0 / h)
        pos, zlow = self.ssao_inputs(d_depth, vp, reversed_z, params.radius, h, w, m)
        low = self.ao_low.ensure(4 * w2 * h2, "SSAO half-resolution buffer")
        r = np.float32(params.radius)
        r2 = r * r
        assert self.taps.buf is not None
        self.k_ssao(self.queue, _lanes_global(w2, h2), LOCAL, pos, d_nrm, self.taps.buf, low,
                    np.int32(w), np.int32(h), np.int32(params.samples), r2, np.float32(1.0) / r2,
                    np.float32(params.bias), _ssao_skip_bias2(params.bias),
                    np.float32(params.strength) / np.float32(params.samples),
                    m[0], m[1], m[2], m[3], sx, sy)
        out = np.empty((h, w), np.float32)
        d_out, in_place = self._result(out)
        self.k_upsample(self.queue, _lanes_global(w, h), LOCAL, d_depth, zlow, low, d_out, m[3],
                        np.int32(w), np.int32(h), sx, sy, np.int32(reversed_z),
                        np.float32(SSAO_UPSAMPLE_DEPTH))
        return self._finish(out, d_out, in_place)

    def fxaa(self, rgb: np.ndarray) -> np.ndarray:
        """FXAA in three kernels: luma; ``fxaa_mark`` copies the image and lists its edge
        pixels; ``fxaa_edges`` computes those in lanes of 8 listed pixels (an image has few:
        ~2% of a 1080p frame of shaded boxes), so no lane waits on a pixel that is no
        edge."""
        img = rgb8(rgb)
        h, w = img.shape[:2]
        n = w * h
        d_rgb = self._in(img)
        d_lum = self.lum.ensure(4 * n, "FXAA luma buffer")
        d_list = self.edge_list.ensure(4 * n, "FXAA edge list")
        self.edge_count.write(self.queue, np.zeros(1, np.int32))
        assert self.edge_count.buf is not None
        out = np.empty_like(img)
        d_out, in_place = self._result(out)
        groups = -(-n // (LANES * 64))
        self.k_luma(self.queue, (groups * 64,), (64,), d_rgb, d_lum, np.int32(n))
        self.k_mark(self.queue, _fxaa_global(w, h), FXAA_LOCAL, d_rgb, d_lum, d_out, d_list,
                    self.edge_count.buf, np.int32(w), np.int32(h))
        self.queue.finish()   # the count is read from host memory (GrowBuffer.read)
        edges = int(self.edge_count.read(self.queue, np.int32, 1)[0])
        if edges:
            items = -(-edges // LANES)
            self.k_edges(self.queue, (-(-items // 64) * 64,), (64,), d_rgb, d_lum, d_out,
                         d_list, self.edge_count.buf, np.int32(w), np.int32(h))
        return self._finish(out, d_out, in_place)


_PASSES: weakref.WeakKeyDictionary[cl.Context, DevicePasses] = weakref.WeakKeyDictionary()


def device_passes(renderer: Any) -> Passes | None:
    """`DevicePasses` for a renderer with an OpenCL ``context`` (one per context), else
    None (the factory `clraster.output.post.register_passes` holds)."""
    ctx = getattr(renderer, "context", None)
    if not isinstance(ctx, cl.Context):
        return None
    made = _PASSES.get(ctx)
    if made is None:
        made = _PASSES[ctx] = DevicePasses(ctx)
    return made


register_passes(device_passes)
