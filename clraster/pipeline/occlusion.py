"""Occlusion: the Hi-Z box test's three-state answer and exact occlusion queries.

Two questions about a list of world-space boxes and a depth buffer rendered with the same
camera (conventions as everywhere in clraster: window depth (z/w + 1)/2 in [0, 1], 1.0 is
the clear value, depth test LESS, row 0 at the top, pixel (x, y) sampled at (x+0.5, y+0.5)):

* **Hi-Z test** (conservative, cheap: one work-item per box against the depth pyramid,
  `clraster.pipeline.stages.pyramid`): `Occlusion` per box. OCCLUDED promises that nothing inside
  the box can produce a sample that passes LESS against the depth buffer, so skipping it
  never changes an image; VISIBLE only means "could not prove otherwise".
* **Exact query** (`query`): per box, the number of pixels at which its surface — its 12
  triangles rasterized with the renderer's own rules (8 sub-pixel bits, top-left rule,
  clipping at near, cull "none") — would pass LESS against the depth buffer, without
  writing it. Like GL_SAMPLES_PASSED, but a pixel counts at most once per box (the box's
  nearest surface there). An OCCLUDED box always has 0 samples; the converse does not hold.

Boxes that cross the near plane (e.g. contain the eye) are VISIBLE for the Hi-Z test, and
their exact count is taken from whatever of their surface lies beyond the near plane (the
part in front of it is clipped away, as the renderer clips): for a box around the eye that
is its inner faces, so with a cleared depth buffer it covers every pixel.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

# the enum is shared with the NumPy twin, so it lives in the lower layer (clraster.pipeline.boxes)
from .boxes import Occlusion, box_geometry

__all__ = ["Occlusion", "OcclusionQuery", "QueryResult", "query", "sphere_boxes"]


@dataclass(frozen=True)
class QueryResult:
    """Answers for K boxes.

    samples: int64 (K,) exact samples passed per box (see `query`).
    hiz: uint8 (K,) `Occlusion` codes of the conservative pyramid test, or None when the
        query was asked with ``pyramid=False``.
    timings_ms: stage → milliseconds (device stages from OpenCL profiling events).
    """

    samples: np.ndarray
    hiz: np.ndarray | None
    timings_ms: dict[str, float] = field(default_factory=dict)


def sphere_boxes(centers: npt.ArrayLike, radii: npt.ArrayLike
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Bounding boxes (mins, maxs), float32 (K, 3) each, of spheres: centres (K, 3), radii
    (K,). Testing a sphere's box is conservative (the box contains the sphere)."""
    c = np.asarray(centers, np.float64).reshape(-1, 3)
    r = np.abs(np.asarray(radii, np.float64).reshape(-1, 1))
    if r.shape[0] != c.shape[0]:
        raise ValueError(f"{c.shape[0]} centres but {r.shape[0]} radii")
    # round outwards so the float32 box still contains the float64 sphere
    lo = (c - r).astype(np.float32)
    hi = (c + r).astype(np.float32)
    lo = np.where(lo > c - r, np.nextafter(lo, np.float32(-np.inf)), lo)
    hi = np.where(hi < c + r, np.nextafter(hi, np.float32(np.inf)), hi)
    return lo, hi


def _check_depth(depth: npt.ArrayLike) -> np.ndarray:
    from ..base.checks import check_size

    d = np.asarray(depth)
    if d.dtype != np.float32 or d.ndim != 2:
        raise ValueError(f"depth must be a float32 (H, W) array (e.g. Frame.depth), got "
                         f"{d.dtype} {d.shape}")
    check_size(d.shape[1], d.shape[0])
    return np.ascontiguousarray(d)


def _check_boxes(boxes_min: npt.ArrayLike, boxes_max: npt.ArrayLike
                 ) -> tuple[np.ndarray, np.ndarray]:
    from ..base.checks import check_boxes

    lo, hi = check_boxes(boxes_min, boxes_max, np.float32, names=("boxes_min", "boxes_max"))
    if lo.shape[0] > (1 << 27) // 12:
        raise ValueError(f"{lo.shape[0]:,} boxes in one query; at most {(1 << 27) // 12:,}")
    return lo, hi


class OcclusionQuery:
    """Reusable Hi-Z tests and exact occlusion queries on one OpenCL device.

    Holds its own command queue, a `PyramidStage` and a `QueryStage` (which has its own
    copies of the vertex/setup/bin stages), so it never touches a renderer's buffers.
    Build one and call it repeatedly; `query` builds a throw-away one per call.

    Args:
        context: OpenCL context, default `clraster.device.default_context()`.
        config: tile size used to bin the box triangles (never changes the counts).
    """

    def __init__(self, context=None, config=None) -> None:
        import pyopencl as cl

        from ..base.config import RasterConfig
        from .device import default_context
        from .stages.pyramid import PyramidStage
        from .stages.query import QueryStage

        self.context = context or default_context()
        self.config = config or RasterConfig()
        self.queue = cl.CommandQueue(
            self.context, properties=cl.command_queue_properties.PROFILING_ENABLE)
        self.pyramid = PyramidStage(self.context, self.config)
        self.query_stage = QueryStage(self.context, self.config)

    def __call__(self, depth: npt.ArrayLike, boxes_min: npt.ArrayLike,
                 boxes_max: npt.ArrayLike, camera, *, pyramid: bool = True) -> QueryResult:
        """See `query`."""
        import pyopencl as cl

        from ..base.checks import mvp_matrix
        from .device import event_ms

        d = _check_depth(depth)
        lo, hi = _check_boxes(boxes_min, boxes_max)
        h, w = d.shape
        vp = mvp_matrix(camera, w, h)
        k = lo.shape[0]
        if k == 0:
            return QueryResult(np.zeros(0, np.int64),
                               np.zeros(0, np.uint8) if pyramid else None)
        q = self.queue
        t0 = time.perf_counter()
        dbuf = cl.Buffer(self.context, cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR,
                         hostbuf=d)
        timings: dict[str, float] = {}
        hiz = None
        if pyramid:
            pyr = self.pyramid.build(q, dbuf, w, h)
            hiz, ev = self.pyramid.enqueue_test(q, pyr, lo, hi, vp, w, h)
            timings["pyramid"] = event_ms(pyr.events)
            timings["hiz test"] = event_ms([ev])
        pool, fd = box_geometry(lo, hi, vp)
        samples, stage_ms = self.query_stage.run(q, pool, fd, k, dbuf, w, h)
        timings.update(stage_ms)
        q.finish()
        timings["total (host)"] = (time.perf_counter() - t0) * 1e3
        return QueryResult(samples, hiz, timings)


def query(renderer_or_context, depth: npt.ArrayLike, boxes_min: npt.ArrayLike,
          boxes_max: npt.ArrayLike, camera, *, pyramid: bool = True) -> QueryResult:
    """Exact occlusion query of world-space boxes against a depth buffer, and optionally
    the conservative Hi-Z verdict for the same boxes, for comparison.

    Args:
        renderer_or_context: a `clraster.Renderer` (its context and tile config are used),
            a `pyopencl.Context`, or None for the default context.
        depth: float32 (H, W) window depths, e.g. ``Frame.depth`` of an ordinary (not
            reversed-Z) frame (1.0 = nothing drawn);
            only read.
        boxes_min, boxes_max: (K, 3) box corners in world space (float32; per axis either
            order gives the same box).
        camera: the camera the depth buffer was rendered with (anything with
            ``view_projection(width, height)``; its matrix is rounded to float32 as the
            renderer does).
        pyramid: also build the depth pyramid and run the Hi-Z test.

    Returns:
        `QueryResult`: samples int64 (K,) — per box, the pixels whose centre one of the box's
        12 triangles (rasterized as the renderer would, cull "none", clipped at near and
        far) covers with window depth strictly less than ``depth`` there, each pixel
        counted once per box; hiz uint8 (K,) `Occlusion` codes (or None). Boxes with
        non-finite corners get 0 samples and VISIBLE.

    For repeated queries build an `OcclusionQuery` once (this builds one per call).
    """
    import pyopencl as cl

    if renderer_or_context is None or isinstance(renderer_or_context, cl.Context):
        oq = OcclusionQuery(renderer_or_context)
    else:
        try:
            ctx, cfg = renderer_or_context.context, renderer_or_context.config
        except AttributeError:
            raise ValueError(f"expected a clraster.Renderer, a pyopencl.Context or None, got "
                             f"{type(renderer_or_context).__name__}") from None
        oq = OcclusionQuery(ctx, cfg)
    return oq(depth, boxes_min, boxes_max, camera, pyramid=pyramid)
