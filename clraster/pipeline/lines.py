"""Line segments: clipped in clip space (Cohen–Sutherland), rasterized with a depth test.

Used to draw a camera's view frustum (`frustum_segments`) and wireframe overlays
(`mesh_edges` + `overlay`) over frames of the triangle renderer. The OpenCL path is
`LineRenderer` / `render_lines` (kernels/lines.cl); the twin's `reference.lines.render_lines`
is its NumPy twin with bit-identical outputs; what both share (input checks, user clip
planes, stats, `LineFrame`) is `clraster.pipeline.segments`.

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
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ..base.checks import check_clip_planes, check_size
from ..world.mesh import Mesh
from .segments import (
    LineFrame,
    check_bias,
    check_depth,
    check_segments,
    check_view_proj,
    clip_to_planes,
    stats_from_status,
    undo_plane_compaction,
)

if TYPE_CHECKING:
    import pyopencl as cl

__all__ = ["LineFrame", "LineRenderer", "frustum_segments", "mesh_edges", "overlay",
           "render_lines"]

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
