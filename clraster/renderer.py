"""The OpenCL renderer: cull → vertex → setup → bin → raster for one frame."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pyopencl as cl

from .config import RasterConfig
from .device import check_process, default_context, event_ms
from .drawlist import PlanCache, plan_frame
from .fates import ClusterFates
from .frame import Frame, FrameStats
from .inputs import check_cull, check_flag, check_size
from .params import FrameParams, FrameTotals
from .stages.chain import StageChain
from .stages.pyramid import PyramidStage
from .stages.raster import RasterOutput
from .twophase import OcclusionHistory, two_phase


class Renderer:
    """Rasterizes meshes on an OpenCL device into depth, triangle-id and barycentric buffers.

    Args:
        width, height: image size in pixels, 1..16384.
        config: tunables (tile size, bin chunks); they never change the output.
        context: an OpenCL context; default `clraster.device.default_context()` (honours
            PYOPENCL_CTX, else the first PoCL CPU device).

    Device buffers are kept and grown between frames; programs are built once per context
    and config. Threads may share a Renderer: its frames are serialized by a lock (one per
    Renderer; use one Renderer per thread for parallel frames). It works only in the process
    that created it: after fork() a child must make its own, and only if its parent never
    used OpenCL (`clraster.device.ForkedProcessError` says why and what to do instead).
    """

    def __init__(self, width: int, height: int, *, config: RasterConfig | None = None,
                 context: cl.Context | None = None) -> None:
        self.width, self.height = check_size(width, height)
        self.config = config or RasterConfig()
        self.context = context or default_context()
        self._pid = os.getpid()
        self._lock = threading.Lock()
        dev = self.context.devices[0]
        need = 12 * self.width * self.height
        if need > dev.max_mem_alloc_size:
            raise ValueError(f"{self.width}x{self.height} needs a {need / 2**20:.0f} MiB "
                             f"barycentric buffer; {dev.name} allocates at most "
                             f"{dev.max_mem_alloc_size / 2**20:.0f} MiB per buffer")
        self.queue = cl.CommandQueue(
            self.context, properties=cl.command_queue_properties.PROFILING_ENABLE)
        self.chain = StageChain(self.context, self.config)
        self.pyramid = PyramidStage(self.context, self.config)
        self._plans = PlanCache()
        self._occlusion = OcclusionHistory()   # two-phase occlusion culling's memory

    def render(self, target, camera, *, cull: str = "back", frustum: bool = True,
               cones: bool = True, occlusion: bool = False, overdraw: bool = False,
               fates: bool = False) -> Frame:
        """Render ``target`` (a `clraster.Mesh` or `clraster.Scene`) seen by ``camera``.

        Args:
            cull: "back" (drop faces that are clockwise in NDC, i.e. counter-clockwise is
                front, the OpenGL default), "front", or "none".
            frustum: cull instances and clusters against the view frustum through their
                BVHs first. Conservative: it never changes the image, only the work.
            cones: cull clusters whose normal cone faces away (with cull "back"/"front").
                Conservative too.
            occlusion: two-phase occlusion culling with a hierarchical depth pyramid: draw
                the clusters that were visible in this renderer's previous frame of the
                same scene (on a first frame: the nearest ones), build the pyramid, test
                every other cluster's box against it, draw those not occluded, and keep
                the visible set for the next frame. Conservative: same image.
            overdraw: also return ``frame.overdraw``, fragments tested per pixel.
            fates: also return ``frame.fates``, a `clraster.fates.ClusterFates`: the fate
                of every cluster of every instance (drawn, frustum-, cone- or
                occlusion-culled); its counts equal the stats' culling funnel.

        Returns:
            A `Frame` (depth, triangle_id, barycentrics, stats); see its docstring for the
            conventions. For a Scene, triangle ids are ``scene.face_base[instance] + face``
            (`Scene.split_ids` splits them). Triangles with a NaN/Inf vertex are dropped
            and counted in ``stats.invalid``.
        """
        check_cull(cull)
        for name, value in (("frustum", frustum), ("cones", cones), ("occlusion", occlusion),
                            ("overdraw", overdraw), ("fates", fates)):
            check_flag(value, name)
        check_process(self._pid)
        with self._lock:
            return self._render(target, camera, cull, frustum, cones, occlusion, overdraw,
                                fates)

    def _render(self, target, camera, cull: str, frustum: bool, cones: bool, occlusion: bool,
                overdraw: bool, fates: bool) -> Frame:
        w, h = self.width, self.height
        t0 = time.perf_counter()
        plan = plan_frame(target, camera, w, h, cull=cull, frustum=frustum, cones=cones,
                          cache=self._plans, keep_cone_culled=fates)
        t_cull = (time.perf_counter() - t0) * 1e3
        counts = dict(plan.draw_list.counts)
        fd = plan.frame
        if fd.n_tris == 0:
            fr = Frame.empty(w, h, FrameStats.from_counts(counts, np.zeros(0, np.uint8)))
            if overdraw:
                fr.overdraw = np.zeros((h, w), np.int32)
            if fates:
                fr.fates = ClusterFates.from_plan(plan)
            return fr
        params = FrameParams.make(w, h, self.config, cull)
        totals = FrameTotals(timings_ms={"cull (host)": t_cull})
        occluded = None
        if not occlusion:
            out = self.chain.draw(self.queue, plan.pool, fd, params, totals,
                                  overdraw=overdraw)
        else:
            def draw(draws, into: RasterOutput | None) -> RasterOutput:
                return self.chain.draw(self.queue, plan.pool, draws, params, totals,
                                       into=into, overdraw=overdraw)

            res = two_phase(plan, self._occlusion, draw, self._hiz, totals, counts)
            out, occluded = res.out, res.occluded_keys
        return Frame(out.depth, out.ids, out.bary, totals.stats(counts), overdraw=out.overdraw,
                     fates=ClusterFates.from_plan(plan, occluded) if fates else None)

    def _hiz(self, out: RasterOutput, rows: np.ndarray, vp32: np.ndarray
             ) -> tuple[np.ndarray, float]:
        """Pyramid of ``out``'s depth and the Hi-Z test of boxes ``rows`` (float32 (6, K))
        under ``vp32`` (float32 (16,)): `Occlusion` codes uint8 (K,) and device ms."""
        w, h = self.width, self.height
        pyr = self.pyramid.build(self.queue, out.bufs[0], w, h)
        verdict, ev = self.pyramid.enqueue_test_rows(self.queue, pyr, rows, vp32, w, h)
        return verdict, event_ms([*pyr.events, ev] if ev else pyr.events)
