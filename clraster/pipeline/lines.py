"""Line segments: clipped in clip space (Cohen–Sutherland), rasterized with a depth test.

Used to draw a camera's view frustum (`frustum_segments`) and wireframe overlays
(`mesh_edges` + `overlay`) over frames of the triangle renderer. The OpenCL path is
`LineRenderer` / `render_lines` (kernels/lines.cl); the twin's `reference.lines.render_lines`
is its NumPy twin with bit-identical outputs.

Conventions (the triangle pipeline's): world → clip ``c = M · [x y z 1]ᵀ`` in float32 with
``M`` an OpenGL view-projection; the view volume is −w ≤ x, y, z ≤ w; window depth
``(z/w + 1)/2`` in [0, 1]; row 0 is the top row and pixel (x, y) has its centre at
(x + 0.5, y + 0.5); window positions snap to 1/256 pixel.

Rules (the kernel header in kernels/lines.cl has the details and the reasons):

* **Clipping**: 6-bit outcodes; both 0 → trivially accepted; a shared bit → trivially
  rejected; otherwise clipped exactly to the view volume (no guard band), in float64, plane
  by plane (near, far, left, right, bottom, top), recomputing outcodes after each clip and
  rejecting the segment as soon as nothing of it is left inside.
* **Endpoint order never matters**: the clipper treats both endpoints alike and the
  rasterizer puts them in a canonical order, so ``(a, b)`` and ``(b, a)`` give identical
  pixels and depths.
* **Rasterization** (aliased, like D3D11/GL): x-major when |dx| ≥ |dy|, else y-major. Along
  the major axis every pixel whose centre lies in the half-open interval [start, end) is lit,
  start being the endpoint with the smaller major coordinate (so the end pixel is excluded,
  like GL's last-pixel rule, and a zero-length segment lights nothing). The minor coordinate
  at the pixel centre is computed exactly in 24.8 fixed point and the pixel whose half-open
  square [k, k + 1) contains it is lit: a tie exactly on a pixel boundary goes down / right.
  A point exactly on the bottom or right image border therefore belongs to no image pixel:
  a segment lying exactly on the bottom (right) border of the view lights nothing, one on
  the top (left) border lights row (column) 0.
* **Depth**: linear in screen space along the segment, float32, clamped to [0, 1]. With a
  depth buffer a fragment is drawn only where ``depth <= buffer[y, x] + depth_bias`` (LEQUAL,
  so lines lying on drawn surfaces show). Among several segments at one pixel the nearest
  wins; ties go to the lower segment index, deterministically.
* **NaN/Inf**: a segment with a non-finite endpoint (or clip position, e.g. float64 input
  beyond float32 range) is dropped and counted in ``stats["invalid"]``.

Stats (``LineFrame.stats``, plain ints): ``segments`` in; partitioned into ``invalid``,
``trivially_rejected``, ``trivially_accepted`` and ``clipped``. Of the clipped,
``clipped_away`` had nothing inside the view volume. ``degenerate``: accepted or clipped
segments with an endpoint at w < FLT_MIN (only the clip-space origin can be inside the view
volume with such a w; it has no window position), dropped. ``rasterized`` = trivially_accepted
+ clipped − clipped_away − degenerate. ``fragments``: pixels the rasterized segments cover
inside the image; ``fragments_passed``: those that passed the depth-buffer test (equal to
fragments without a depth buffer).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from .inputs import check_clip_planes, check_mat4, check_size
from .layout import (
    LS_ACCEPTED,
    LS_ACCEPTED_DEGENERATE,
    LS_CLIPPED,
    LS_CLIPPED_AWAY,
    LS_CLIPPED_DEGENERATE,
    LS_INVALID,
    LS_REJECTED,
)
from .mesh import Mesh

if TYPE_CHECKING:
    import pyopencl as cl

__all__ = ["LineFrame", "LineRenderer", "frustum_segments", "mesh_edges", "overlay",
           "render_lines"]

# Segment status codes LS_* (kernels/lines.cl) are defined in clraster/layout.py, imported above.

#: Segment indices are int32 in ``line_id``, and 0xFFFFFFFF clears the resolve buffer.
MAX_SEGMENTS = int(np.iinfo(np.int32).max)

STAT_KEYS = ("segments", "invalid", "trivially_rejected", "trivially_accepted", "clipped",
             "clipped_away", "degenerate", "rasterized", "fragments", "fragments_passed")


def clip_to_planes(seg: np.ndarray, planes: np.ndarray | None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clip world-space segments against user clip planes before the view volume (both
    renderers call this, so they see the same segments), as OpenGL clips lines against
    gl_ClipDistance: the part of each segment with a·x + b·y + c·z + d >= 0 for every plane.

    Per segment, the kept parameter range [t0, t1] of p0 + t·(p1 − p0) is narrowed plane by
    plane (Liang–Barsky) with distances in float64 from the float32 endpoints; a clipped
    endpoint is formed in float64 and rounded to float32 once.

    Args:
        seg: float32 (N, 2, 3) (`check_segments`). planes: float64 (K, 4) or None.

    Returns:
        (segments float32 (M, 2, 3) to draw, their indices into ``seg`` int64 (M,),
        status uint8 (N,): LS_REJECTED where both endpoints lie outside one plane,
        LS_CLIPPED_AWAY where the planes together leave nothing, LS_CLIPPED where a plane
        cut the segment (refined by the view-volume result, `merge_plane_status`), 255
        where no plane touched it).
    """
    n = seg.shape[0]
    status = np.full(n, 255, np.uint8)
    if planes is None or n == 0:
        return seg, np.arange(n, dtype=np.int64), status
    p = seg.astype(np.float64)
    with np.errstate(all="ignore"):   # NaN/Inf endpoints: no plane test, the kernel says
        d = np.einsum("nej,kj->nek", p, planes[:, :3]) + planes[:, 3]   # (N, 2, K)
        out0, out1 = d[:, 0] < 0.0, d[:, 1] < 0.0
        t = d[:, 0] / (d[:, 0] - d[:, 1])
        t0 = np.where(out0 & ~out1, t, 0.0).max(axis=1)
        t1 = np.where(out1 & ~out0, t, 1.0).min(axis=1)
    rejected = (out0 & out1).any(axis=1)
    cut = (out0 | out1).any(axis=1) & ~rejected
    away = cut & ~(t0 <= t1)
    status[cut] = LS_CLIPPED
    status[away] = LS_CLIPPED_AWAY
    status[rejected] = LS_REJECTED
    keep = np.flatnonzero((status == 255) | (status == LS_CLIPPED))
    out = seg[keep].copy()
    c = np.flatnonzero(status[keep] == LS_CLIPPED)
    if c.size:
        a, b = p[keep[c], 0], p[keep[c], 1]
        out[c, 0] = (a + t0[keep[c], None] * (b - a)).astype(np.float32)
        out[c, 1] = (a + t1[keep[c], None] * (b - a)).astype(np.float32)
    return np.ascontiguousarray(out), keep, status


def undo_plane_compaction(line_id: np.ndarray, status: np.ndarray, keep: np.ndarray,
                          pre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Line ids and statuses of the segments `clip_to_planes` drew (``keep``) back in terms
    of the caller's segments: ids int32 (H, W) mapped to input indices, statuses merged
    (`merge_plane_status`)."""
    line_id = np.where(line_id >= 0, keep[np.maximum(line_id, 0)], -1).astype(np.int32)
    return line_id, merge_plane_status(pre, keep, status)


def merge_plane_status(pre: np.ndarray, keep: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Per-segment status (uint8 (N,)) from `clip_to_planes`' ``pre`` and the view-volume
    status ``kernel`` of the drawn segments ``keep``: untouched segments take the kernel's;
    a segment a user plane cut counts as clipped (its view-volume result moved to the
    clipped codes: accepted → LS_CLIPPED, degenerate → LS_CLIPPED_DEGENERATE, rejected or
    clipped away → LS_CLIPPED_AWAY)."""
    st = pre.copy()
    k = np.asarray(kernel, np.uint8)
    cut = st[keep] == LS_CLIPPED
    moved = np.select([k == LS_ACCEPTED, k == LS_ACCEPTED_DEGENERATE,
                       (k == LS_REJECTED) | (k == LS_CLIPPED_AWAY)],
                      [LS_CLIPPED, LS_CLIPPED_DEGENERATE, LS_CLIPPED_AWAY],
                      k.astype(np.int64)).astype(np.uint8)
    st[keep] = np.where(cut, moved, k).astype(np.uint8)
    return st


def stats_from_status(status: np.ndarray, fragments: int, passed: int) -> dict[str, int]:
    """Stats dict from the per-segment status codes (uint8/int (N,)) and fragment counts."""
    c = np.bincount(np.asarray(status, np.int64), minlength=8)
    return {
        "segments": int(status.size),
        "invalid": int(c[LS_INVALID]),
        "trivially_rejected": int(c[LS_REJECTED]),
        "trivially_accepted": int(c[LS_ACCEPTED] + c[LS_ACCEPTED_DEGENERATE]),
        "clipped": int(c[LS_CLIPPED] + c[LS_CLIPPED_AWAY] + c[LS_CLIPPED_DEGENERATE]),
        "clipped_away": int(c[LS_CLIPPED_AWAY]),
        "degenerate": int(c[LS_ACCEPTED_DEGENERATE] + c[LS_CLIPPED_DEGENERATE]),
        "rasterized": int(c[LS_ACCEPTED] + c[LS_CLIPPED]),
        "fragments": int(fragments),
        "fragments_passed": int(passed),
    }


@dataclass
class LineFrame:
    """Rendered line segments.

    Attributes:
        line_id: (H, W) int32 index of the segment drawn at each pixel, −1 where none.
        depth: (H, W) float32 window depth of that segment's fragment, 1.0 where none.
        stats: counts (see the module docstring): segments, invalid, trivially_rejected,
            trivially_accepted, clipped, clipped_away, degenerate, rasterized, fragments,
            fragments_passed.
    """

    line_id: np.ndarray
    depth: np.ndarray
    stats: dict[str, int] = field(default_factory=dict)

    @classmethod
    def empty(cls, width: int, height: int, stats: dict[str, int] | None = None) -> LineFrame:
        return cls(np.full((height, width), -1, np.int32), np.ones((height, width), np.float32),
                   stats if stats is not None else stats_from_status(np.zeros(0, np.uint8), 0, 0))

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: pixels where some segment is drawn."""
        return self.line_id >= 0

    @property
    def width(self) -> int:
        return int(self.line_id.shape[1])

    @property
    def height(self) -> int:
        return int(self.line_id.shape[0])


# -- input validation (shared with the NumPy twin) ------------------------------------------


def check_segments(segments: npt.ArrayLike) -> np.ndarray:
    """``segments`` as a C-contiguous float32 (N, 2, 3) array (never modified); values beyond
    float32 range become ±Inf (and those segments count as invalid)."""
    try:
        arr = np.asarray(segments)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"segments must be an (N, 2, 3) array of world-space endpoints; "
                         f"could not convert {type(segments).__name__} ({exc})") from exc
    if arr.size == 0 and arr.ndim == 1:
        arr = arr.reshape(0, 2, 3)
    if arr.ndim != 3 or arr.shape[1:] != (2, 3):
        raise ValueError(f"segments must have shape (N, 2, 3) (N segments, 2 endpoints, "
                         f"x y z), got shape {arr.shape}; one segment is segments[None]")
    if arr.dtype.kind not in "iuf" and not (arr.size == 0 and not isinstance(segments,
                                                                             np.ndarray)):
        raise ValueError(f"segments must have a real numeric dtype (float or integer), got "
                         f"{arr.dtype}")
    if arr.shape[0] > MAX_SEGMENTS - 1:
        raise ValueError(f"too many segments ({arr.shape[0]}): line ids are int32, so at most "
                         f"{MAX_SEGMENTS - 1} per call; draw them in several calls")
    with np.errstate(over="ignore", invalid="ignore"):
        return np.ascontiguousarray(arr, dtype=np.float32)


def check_view_proj(view_proj: Any, width: int, height: int) -> np.ndarray:
    """Row-major float32 (4, 4) view-projection from a matrix or a camera (anything with
    ``view_projection(width, height)``, e.g. `clraster.Camera`), validated."""
    if hasattr(view_proj, "view_projection"):
        view_proj = view_proj.view_projection(width, height)
    m = check_mat4(view_proj, "view_proj (projection @ view, or a clraster.Camera)")
    with np.errstate(over="ignore"):
        m32 = m.astype(np.float32)
    if not np.all(np.isfinite(m32)):
        raise ValueError("view_proj overflows float32 (an entry above ~3.4e38); rescale it")
    return np.ascontiguousarray(m32)


def check_depth(depth: Any, width: int, height: int) -> np.ndarray | None:
    """The optional depth buffer: None, or a C-contiguous float32 (H, W) array without NaN."""
    if depth is None:
        return None
    if not isinstance(depth, np.ndarray):
        raise ValueError(f"depth must be a float32 (H, W) NumPy array (e.g. Frame.depth) or "
                         f"None, got {type(depth).__name__}")
    if depth.dtype != np.float32:
        raise ValueError(f"depth must have dtype float32 (window depth, e.g. Frame.depth), got "
                         f"{depth.dtype}; convert with depth.astype(np.float32)")
    if depth.shape != (height, width):
        raise ValueError(f"depth must have shape (height, width) = ({height}, {width}) to "
                         f"match the image, got {depth.shape}")
    if np.isnan(depth).any():
        raise ValueError("depth contains NaN; a depth buffer holds window depths in [0, 1] "
                         "(1.0 = nothing drawn)")
    return np.ascontiguousarray(depth)


def check_bias(depth_bias: Any) -> np.float32:
    if isinstance(depth_bias, bool) or not isinstance(depth_bias, (int, float, np.integer,
                                                                   np.floating)):
        raise ValueError(f"depth_bias must be a real number, got {depth_bias!r}")
    with np.errstate(over="ignore"):
        b = np.float32(depth_bias)
    if not np.isfinite(b):
        raise ValueError(f"depth_bias must be finite in float32, got {depth_bias!r}")
    return b


# -- OpenCL renderer ------------------------------------------------------------------------


class LineRenderer:
    """Rasterizes line segments on an OpenCL device into line-id and depth buffers.

    Args:
        width, height: image size in pixels, 1..16384.
        context: an OpenCL context; default `clraster.device.default_context()`.

    Device buffers are kept and grown between calls; the program is built once per context.
    Not thread-safe; use one per thread.
    """

    def __init__(self, width: int, height: int, *, context: cl.Context | None = None) -> None:
        import pyopencl as cl

        from .device import default_context
        from .stages.lines import LineStage

        self.width, self.height = check_size(width, height)
        self.context = context or default_context()
        self.queue = cl.CommandQueue(self.context)
        self.stage = LineStage(self.context)

    def render(self, segments: npt.ArrayLike, view_proj: Any, *,
               depth: np.ndarray | None = None, depth_bias: float = 0.0,
               clip_planes: Any = None) -> LineFrame:
        """Draw world-space segments seen through ``view_proj``.

        Args:
            segments: (N, 2, 3) world-space endpoints, any real dtype (converted to float32).
                (0, 2, 3) gives an empty frame.
            view_proj: (4, 4) OpenGL ``projection @ view`` (column vectors), or a camera
                object (`clraster.Camera`), whose ``view_projection(width, height)`` is used.
            depth: optional (H, W) float32 window depth buffer (e.g. ``Frame.depth``): a
                fragment is drawn only where its depth ≤ ``depth[y, x] + depth_bias``.
                Without it every fragment is drawn (nearest wins among the segments).
            depth_bias: added to the buffer's depth (float32) in the test.
            clip_planes: up to 8 world-space planes (a, b, c, d) keeping a·x + b·y + c·z + d
                >= 0, as `Renderer.render`'s: segments are clipped against them first
                (`clip_to_planes`); line ids stay the input indices.

        Returns:
            A `LineFrame`. See the module docstring for the rules; results are deterministic
            and identical to the twin's `reference.lines.render_lines`.

        Raises:
            ValueError: wrong shapes or dtypes, non-finite view_proj or depth_bias, NaN in
                the depth buffer.
        """
        w, h = self.width, self.height
        seg = check_segments(segments)
        m = check_view_proj(view_proj, w, h)
        dbuf = check_depth(depth, w, h)
        bias = check_bias(depth_bias)
        planes = check_clip_planes(clip_planes)
        if seg.shape[0] == 0:
            return LineFrame.empty(w, h)
        drawn, keep, pre = clip_to_planes(seg, planes)
        if drawn.shape[0] == 0:
            return LineFrame.empty(w, h, stats_from_status(pre, 0, 0))
        line_id, zbuf, status, frags, passed = self.stage.run(self.queue, drawn, m, w, h,
                                                              dbuf, bias)
        if planes is not None:
            line_id, status = undo_plane_compaction(line_id, status, keep, pre)
        return LineFrame(line_id, zbuf, stats_from_status(status, frags, passed))


def render_lines(segments: npt.ArrayLike, view_proj: Any, width: int, height: int, *,
                 depth: np.ndarray | None = None, depth_bias: float = 0.0,
                 context: cl.Context | None = None, clip_planes: Any = None) -> LineFrame:
    """Convenience: `LineRenderer(width, height).render(...)` for one call."""
    return LineRenderer(width, height, context=context).render(
        segments, view_proj, depth=depth, depth_bias=depth_bias, clip_planes=clip_planes)


# -- geometry helpers -----------------------------------------------------------------------

#: The 12 edges of the NDC cube as corner-index pairs; corner k is
#: (x, y, z) = (±1, ±1, ±1) with bit 0 of k for x (+1 if set), bit 1 for y, bit 2 for z.
#: Order: the 4 near-plane edges, the 4 far-plane edges, the 4 edges from near to far.
CUBE_EDGES = np.array([(0, 1), (2, 3), (0, 2), (1, 3),
                       (4, 5), (6, 7), (4, 6), (5, 7),
                       (0, 4), (1, 5), (2, 6), (3, 7)], np.int64)


def ndc_corners() -> np.ndarray:
    """(8, 3) float64 corners of the NDC cube, indexed as in `CUBE_EDGES`."""
    k = np.arange(8)
    return np.stack([(k & 1) * 2 - 1, ((k >> 1) & 1) * 2 - 1, ((k >> 2) & 1) * 2 - 1],
                    axis=1).astype(np.float64)


def frustum_segments(view_proj: npt.ArrayLike) -> np.ndarray:
    """(12, 2, 3) float64 world-space edges of the view frustum of ``view_proj``.

    The corners are ``view_proj⁻¹ · (±1, ±1, ±1, 1)`` divided by w (perspective or
    orthographic alike); edge order and corner order as in `CUBE_EDGES`. For a camera, pass
    ``camera.view_projection(width, height)`` (the aspect ratio comes from the image size).

    Raises:
        ValueError: not a finite (4, 4) matrix, singular, or a frustum corner at infinity
            (e.g. an infinite far plane).
    """
    if hasattr(view_proj, "view_projection"):
        raise ValueError("frustum_segments needs a (4, 4) matrix: pass "
                         "camera.view_projection(width, height)")
    m = np.asarray(view_proj)
    if m.dtype.kind not in "iuf" or m.shape != (4, 4):
        raise ValueError(f"view_proj must be a real (4, 4) matrix, got shape {m.shape} dtype "
                         f"{m.dtype}")
    m = m.astype(np.float64)
    if not np.all(np.isfinite(m)):
        raise ValueError("view_proj must be finite; it contains NaN or Inf")
    try:
        inv = np.linalg.inv(m)
    except np.linalg.LinAlgError:
        raise ValueError("view_proj is singular: it has no frustum to draw") from None
    c = np.concatenate([ndc_corners(), np.ones((8, 1))], axis=1) @ inv.T
    scale = np.abs(c[:, :3]).max(axis=1)
    if not np.all(np.abs(c[:, 3]) > 1e-12 * np.maximum(scale, 1e-300)):
        raise ValueError("a frustum corner lies at infinity (w = 0 after inversion): the "
                         "projection has an infinite far plane or is degenerate")
    world = c[:, :3] / c[:, 3:]
    if not np.all(np.isfinite(world)):
        raise ValueError("the frustum corners are not finite; view_proj is ill-conditioned")
    return world[CUBE_EDGES]


def mesh_edges(mesh_or_vertices_faces: Mesh | tuple[npt.ArrayLike, npt.ArrayLike]
               ) -> np.ndarray:
    """(E, 2, 3) float64 unique undirected edges of a mesh, for wireframe overlays.

    Accepts a `clraster.Mesh` or a ``(vertices, faces)`` pair (validated as Mesh does).
    Each edge appears once, as (lower vertex index, higher vertex index), sorted by that
    pair; zero-length index pairs (a face repeating a vertex index) are left out.
    """
    mesh = mesh_or_vertices_faces
    if not isinstance(mesh, Mesh):
        if not (isinstance(mesh, Sequence) and len(mesh) == 2):
            raise ValueError(f"expected a clraster.Mesh or a (vertices, faces) pair, got "
                             f"{type(mesh).__name__}")
        mesh = Mesh(mesh[0], mesh[1])
    f = mesh.faces.astype(np.int64)
    e = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    e = np.sort(e, axis=1)
    e = e[e[:, 0] != e[:, 1]]
    e = np.unique(e, axis=0) if e.size else e.reshape(0, 2)
    return mesh.vertices.astype(np.float64)[e]


def overlay(image: npt.ArrayLike, frame: LineFrame, color: Sequence[int]) -> np.ndarray:
    """A copy of ``image`` ((H, W, 3) uint8, e.g. `clraster.shade.shade`) with the pixels of
    ``frame.mask`` set to ``color`` (3 integers in 0..255)."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must be an (H, W, 3) uint8 RGB array, got shape {img.shape} "
                         f"dtype {img.dtype}")
    if img.shape[:2] != frame.line_id.shape:
        raise ValueError(f"image is {img.shape[1]}x{img.shape[0]} but the line frame is "
                         f"{frame.width}x{frame.height}; render the lines at the image size")
    col = np.asarray(color)
    if (col.shape != (3,) or col.dtype.kind not in "iu" or int(col.min()) < 0
            or int(col.max()) > 255):
        raise ValueError(f"color must be 3 integers in 0..255 (R, G, B), got {color!r}")
    out = img.copy()
    out[frame.mask] = col.astype(np.uint8)
    return out
