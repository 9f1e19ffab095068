"""The OpenCL renderer: cull → vertex → setup → bin → raster for one frame."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pyopencl as cl

from .config import RasterConfig, guard_band_factors
from .device import check_process, default_context
from .drawlist import PlanCache, key_boxes, plan_frame, subset
from .fates import ClusterFates
from .frame import Frame, FrameStats
from .frustum import eye_from_view_proj
from .inputs import check_cull, check_flag, check_size
from .occlusion import Occlusion
from .stages.bin import BinStage
from .stages.geometry import GeometryStage
from .stages.pyramid import PyramidStage
from .stages.raster import RasterOutput, RasterStage
from .stages.setup import SetupStage
from .stages.vertex import VertexStage

#: First frame of occlusion culling: at least this many of the nearest clusters (or 1/8 of
#: those that survive frustum culling, if more) are drawn before the first pyramid.
OCCLUSION_FIRST_CLUSTERS = 256


def eye_position(view_proj: np.ndarray) -> np.ndarray | None:
    """World eye point of a perspective view-projection, None for an orthographic one."""
    e = eye_from_view_proj(view_proj)
    return None if abs(e[3]) < 1e-300 else e[:3] / e[3]


def view_direction(view_proj: np.ndarray) -> np.ndarray:
    """World direction the view looks along (normal of the near plane), unit length."""
    n = view_proj[3, :3] + view_proj[2, :3]
    return n / np.linalg.norm(n)


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
        self.vertex = VertexStage(self.context, self.config)
        self.setup = SetupStage(self.context, self.config)
        self.binning = BinStage(self.context, self.config)
        self.raster = RasterStage(self.context, self.config)
        self.geometry = GeometryStage(self.context)
        self.pyramid = PyramidStage(self.context, self.config)
        self._plans = PlanCache()
        self._visible: np.ndarray | None = None   # occlusion: visible keys of last frame
        self._visible_key: tuple | None = None
        self._boxes: tuple | None = None   # occlusion: world boxes of every key, + rows
        self._boxes_key: tuple | None = None

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
        self.geometry.upload_pool(self.queue, plan.pool)
        timings = {"cull (host)": t_cull}
        if not occlusion:
            out, acc = self._pass(fd, cull, None, overdraw, timings)
        else:
            out, acc = self._two_phase(plan, cull, overdraw, timings, counts)
        stats = FrameStats.from_counts(counts, np.concatenate(acc["status"]),
                                       clip_pieces=acc["clip_pieces"],
                                       binned_entries=acc["binned_entries"],
                                       fragments_tested=acc["tested"],
                                       fragments_passed=acc["passed"])
        stats.timings_ms = timings
        return Frame(out.depth, out.ids, out.bary, stats, overdraw=out.overdraw,
                     fates=ClusterFates.from_plan(plan, acc.get("occluded")) if fates else None)

    def _pass(self, fd, cull: str, into, overdraw: bool, timings: dict, acc: dict | None = None
              ):
        """Run vertex → setup → bin → raster over the draws ``fd``; accumulate counts and
        device times into ``acc`` / ``timings``."""
        w, h = self.width, self.height
        acc = acc if acc is not None else {"status": [], "clip_pieces": 0,
                                           "binned_entries": 0, "tested": 0, "passed": 0}
        if fd.n_tris == 0:
            if into is None:   # nothing to draw yet: a cleared frame to continue from
                into = RasterOutput.allocate(self.context, w, h, overdraw)
                into.clear()
            return into, acc
        q = self.queue
        kx, ky = guard_band_factors(w, h)
        self.geometry.upload_frame(q, fd)
        geo = self.geometry.buffers
        n_draws, m = fd.draws.shape[0], fd.n_tris
        ev_v = self.vertex.run(q, geo, n_draws, fd.n_verts, kx, ky, w, h)
        cb = self.vertex.buffers
        p, ev_s = self.setup.run(q, cb.clip.buf, cb.outcode.buf, cb.win.buf, geo, n_draws, m,
                                 w, h, cull, kx, ky)
        sb = self.setup.buffers
        e, ev_b = self.binning.run(q, sb.status.buf, sb.clip_count.buf, sb.clip_offset.buf,
                                   sb.pieces.buf, sb.clip_pieces.buf, m, w, h)
        bb = self.binning.buffers
        out, tstats, ev_r = self.raster.run(q, sb.clip_bary.buf, bb.tile_start.buf,
                                            bb.entries.buf, w, h, into=into,
                                            overdraw=overdraw)
        status = np.empty(m, np.uint8)
        cl.enqueue_copy(q, status, sb.status.buf, is_blocking=True)
        acc["status"].append(status)
        acc["clip_pieces"] += p
        acc["binned_entries"] += e
        acc["tested"] += int(tstats[:, 0].sum())
        acc["passed"] += int(tstats[:, 1].sum())
        for k, evs in (("vertex", [ev_v]), ("setup", ev_s), ("bin", ev_b), ("raster", [ev_r])):
            timings[k] = timings.get(k, 0.0) + _ms(evs)
        return out, acc

    def _two_phase(self, plan, cull: str, overdraw: bool, timings: dict, counts: dict):
        """Two-phase occlusion culling (see `render`); returns (outputs, accumulated counts)
        and adds the occlusion rows to ``counts``."""
        w, h = self.width, self.height
        pool, fd, scene = plan.pool, plan.frame, plan.scene
        d = fd.draws
        keys = pool.instance_key_base[d["instance"]] + (
            d["cluster"] - pool.mesh_cluster_base[pool.instance_mesh[d["instance"]]])
        # the scene object itself is kept and compared with `is` (not its id(), which a
        # new scene can reuse once the old one is freed), with its version
        version = getattr(scene, "version", 0)
        if self._boxes_key is None or not (self._boxes_key[0] is scene
                                           and self._boxes_key[1] == version):
            wlo, whi, wbounded = key_boxes(pool, scene)
            # + the boxes in the Hi-Z test's layout, float32 (6, K), gathered per frame
            self._boxes = (wlo, whi, wbounded,
                           np.ascontiguousarray(np.vstack([wlo.T, whi.T]).astype(np.float32)))
            self._boxes_key = (scene, version)
        wlo, whi, wbounded, box_rows = self._boxes
        bounded = wbounded[keys]
        rows = np.take(box_rows, keys, axis=1)
        vp32 = plan.view_proj.astype(np.float32).reshape(-1)
        hist = self._visible if (self._visible_key is not None
                                 and self._visible_key[0] is scene
                                 and self._visible_key[1] == version) else None
        first = hist[keys] if hist is not None else None
        if first is None or not first.any():
            # first frame, or a camera cut (none of last frame's visible clusters is in
            # view): the nearest clusters, front to back, up to a budget
            vp_inv_eye = eye_position(plan.view_proj)
            centre = 0.5 * (wlo[keys] + whi[keys])
            dist = np.linalg.norm(centre - vp_inv_eye, axis=1) if vp_inv_eye is not None \
                else centre @ view_direction(plan.view_proj)
            budget = max(OCCLUSION_FIRST_CLUSTERS, d.size // 8)
            first = np.zeros(d.size, bool)
            first[np.argsort(dist, kind="stable")[:budget]] = True
        first |= ~bounded
        out, acc = self._pass(subset(pool, fd, first), cull, None, overdraw, timings)
        rest = ~first
        t0 = time.perf_counter()
        verdict = np.zeros(d.size, np.uint8)
        if rest.any():
            pyr = self.pyramid.build(self.queue, out.bufs[0], w, h)
            verdict[rest], ev = self.pyramid.enqueue_test_rows(
                self.queue, pyr, np.compress(rest, rows, axis=1), vp32, w, h)
            timings["pyramid+test"] = _ms([*pyr.events, ev] if ev else pyr.events)
        second = rest & (verdict == Occlusion.VISIBLE)
        occluded = rest & ~second
        out, acc = self._pass(subset(pool, fd, second), cull, out, overdraw, timings, acc)
        # visibility for the next frame: everything drawn whose box is not hidden in the
        # final depth buffer
        drawn = first | second
        pyr = self.pyramid.build(self.queue, out.bufs[0], w, h)
        vis = np.zeros(d.size, bool)
        if drawn.any():
            v2, _ = self.pyramid.enqueue_test_rows(self.queue, pyr,
                                                   np.compress(drawn, rows, axis=1), vp32,
                                                   w, h)
            vis[drawn] = (v2 == Occlusion.VISIBLE) | ~bounded[drawn]
        total_keys = int(pool.instance_key_base[-1])
        self._visible = np.zeros(total_keys, bool)
        self._visible[keys[vis]] = True
        self._visible_key = (scene, version)
        timings["occlusion (host)"] = (time.perf_counter() - t0) * 1e3 - timings.get(
            "pyramid+test", 0.0)
        counts["clusters_occlusion_culled"] = int(occluded.sum())
        counts["triangles_occlusion_culled"] = int(
            pool.clusters[d["cluster"][occluded], 1].sum(dtype=np.int64))
        counts["clusters_phase1"] = int(first.sum())
        counts["clusters_phase2"] = int(second.sum())
        acc["occluded"] = keys[occluded]
        return out, acc


def _ms(events: list[cl.Event]) -> float:
    """Sum of device execution times of ``events`` in milliseconds."""
    return sum((ev.profile.end - ev.profile.start) for ev in events) * 1e-6
