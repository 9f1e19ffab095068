"""Constants and record layouts shared by the host (Python) and the kernels (OpenCL C).

This module is their one source. `c_header` turns it into C text — a ``#define`` per shared
constant and a ``typedef struct`` per record dtype — which
`clraster.pipeline.device.kernel_source` puts in place of the ``#include "layout.h"`` line of
``kernels/common.h``, so every kernel is built with exactly these values; no kernel file
spells any of them out by hand.
tests/test_layout.py builds a probe kernel through the same path and compares what the
compiler sees (sizeof, offsetof, the value of every define) with the values here.

Records are NumPy structured dtypes with no implicit padding: every field sits at a multiple
of its scalar size and the record size is a multiple of the largest one, so the packed NumPy
layout and the C compiler's layout are the same (`c_header` refuses any other dtype).

Tunables (tile size, the raster's and query's loop shapes, chunk counts) are not here: they
are in `clraster.base.config`, and those the kernels read reach them as ``-D`` build options
(`RasterConfig.build_options`). This module imports nothing from
clraster, so every layer may import it.
"""

from __future__ import annotations

import re
import textwrap
from collections.abc import Mapping
from typing import cast

import numpy as np

# ---- Fixed point -------------------------------------------------------------------------

#: Vertices snap to 1/256 pixel, as D3D11 requires (a rule, not a tunable: see config).
SUBPIXEL_BITS = 8
SUBPIXEL_ONE = 1 << SUBPIXEL_BITS
#: User clip planes per frame (`Renderer.render(clip_planes=...)`), as OpenGL's minimum
#: GL_MAX_CLIP_DISTANCES: one bit each in the vertex stage's ucode.
USER_PLANES_MAX = 8
#: Triangles clipped by near, far, 4 guard-band planes and the user planes have at most
#: 3 + 6 + 8 vertices.
MAX_CLIP_VERTICES = 3 + 6 + USER_PLANES_MAX
#: Vertex slots of the clipper's polygon (kernels/setup.cl, reference/setup.py). More than
#: MAX_CLIP_VERTICES: float rounding can make a clipped polygon a hair non-convex.
POLY_MAX = 24

# ---- Vertex stage ------------------------------------------------------------------------

# Outcode bits written by the vertex stage. Bits 0..5 are the classic 6-bit frustum outcode;
# 6..9 say the vertex is outside the guard band (x/y clipping needed); bit 10 marks NaN/Inf.
OC_X_NEG, OC_X_POS, OC_Y_NEG, OC_Y_POS, OC_Z_NEG, OC_Z_POS = 1, 2, 4, 8, 16, 32
OC_FRUSTUM = 63
OC_GB_X_NEG, OC_GB_X_POS, OC_GB_Y_NEG, OC_GB_Y_POS = 64, 128, 256, 512
OC_INVALID = 1024
#: w <= 0: the vertex has no window position; never set alone on a drawn vertex.
OC_W_NONPOS = 2048
#: Planes that force a triangle through the clipper: near, far and the four guard-band planes.
OC_NEEDS_CLIP = OC_Z_NEG | OC_Z_POS | OC_GB_X_NEG | OC_GB_X_POS | OC_GB_Y_NEG | OC_GB_Y_POS

# ---- Triangle setup ----------------------------------------------------------------------

# Per-triangle status written by triangle setup.
ST_RASTER = 0  #: unclipped, one setup record at its own slot, sent to binning
ST_CLIPPED = 1  #: went through the clipper; 0..7 pieces in the clipped-piece buffer
ST_INVALID = 2  #: a vertex is NaN/Inf (or its clip position is): dropped and counted
ST_TRIVIAL_REJECT = 3  #: all three vertices outside one frustum plane or one user clip plane
ST_BACKFACE = 4  #: culled by the cull mode
ST_DEGENERATE = 5  #: zero area after the fixed-point snap
ST_NO_SAMPLE = 6  #: covers no pixel centre (box holds none, or a <= 4x4 box tested exactly)
STATUS_NAMES = ("raster", "clipped", "invalid", "trivial_reject", "backface", "degenerate",
                "no_sample")

# Piece flags.
PF_SWAPPED = 1  #: vertices 1 and 2 were swapped to make the window-space area positive
PF_CLIPPED = 2  #: made by the clipper; parent barycentrics live in the clipped-bary buffer
PF_INDEX_SHIFT = 2  #: clipped pieces: flags >> 2 is their index in the clipped-bary buffer
#: Piece.cover: the pixel boxes whose coverage setup tests centre by centre are at most
#: COVER_SPAN x COVER_SPAN centres; bit COVER_SPAN·oy + ox holds the centre (bb_min x + ox,
#: bb_min y + oy), and COVER_KNOWN is set with them; 0 when the box is larger (the raster
#: evaluates the edges then)
COVER_SPAN = 4
COVER_KNOWN = 1 << 16

# Cull modes (the setup kernel's `cull` argument).
CULL_NONE, CULL_BACK, CULL_FRONT = 0, 1, 2
CULL_MODES = {"none": CULL_NONE, "back": CULL_BACK, "front": CULL_FRONT}

# ---- Clusters and draws ------------------------------------------------------------------

#: Clusters (meshlets) have at most CLUSTER_MAX triangles and CLUSTER_MAX vertices. The
#: clipper's kernels run one work-item per (draw, local triangle): work-item g serves draw
#: g >> CLUSTER_LOG2, local index g & (CLUSTER_MAX - 1); setup_triangles one per draw, its
#: triangles SETUP_LANES at a time, after making the draw's vertices VERTEX_LANES at a
#: time (kernels/setup.cl draw_vertices).
CLUSTER_LOG2 = 7
CLUSTER_MAX = 1 << CLUSTER_LOG2
VERTEX_LANES = 8
SETUP_LANES = 8
DRAW_INSIDE = 1  #: draw flag: cluster inside the frustum by a margin, no clip tests needed
#: Draw flag: the instance's transform mirrors (negative determinant). Its faces keep their
#: outward side (glTF 2.0, trimesh's apply_transform): setup swaps the cull sense (and the
#: meaning of "front") for such draws, since their screen winding is reversed.
DRAW_MIRRORED = 2
#: Draw flag: no triangle of the cluster can need clipping (inside the near and far planes
#: and the guard band by a margin: `clraster.culling.cull.ViewCull.clip_free`). Read by
#: the host only (`GeometryStage.upload_frame`: setup's clip count is not waited for).
DRAW_NO_CLIP = 4

# ---- Depth pyramid and occlusion ---------------------------------------------------------

#: Levels made per launch of pyramid_reduce (kernels/pyramid.cl): each work-item reduces a
#: (1 << PYR_LOG2)² block of its source level through PYR_LOG2 levels in private memory.
PYR_LOG2 = 6



def level_shapes(width: int, height: int) -> list[tuple[int, int]]:
    """(height, width) of every level of the depth pyramid of a width × height depth
    buffer, level 0 first: level k+1 is ceil(w_k/2) × ceil(h_k/2), down to (1, 1). The host's
    pyramid buffer (one level after another) and the NumPy twin are laid out by it."""
    w, h = int(width), int(height)
    shapes = [(h, w)]
    while w > 1 or h > 1:
        w, h = (w + 1) // 2, (h + 1) // 2
        shapes.append((h, w))
    return shapes


# Results of the Hi-Z box test (the values of `clraster.occlusion.Occlusion`).
OCC_VISIBLE, OCC_OCCLUDED, OCC_VIEW_CULLED = 0, 1, 2

# Error model of the box test (kernels/pyramid.cl has the derivation).
HIZ_EPS = np.float32(2.0**-18)  #: relative clip-space error bound, per unit of Σ|m_rc · p_c|
HIZ_DEPTH_SLACK = np.float32(2.0**-18)  #: subtracted from the box's nearest window depth
HIZ_PIXEL_SLACK = np.float32(0.0625)  #: window-space widening of the box's screen rectangle, px

#: Words (int32) of a face's row in the resolve and shading kernels' face table
#: (`clraster.pipeline.resolving.ResolveTables.face_rows`): its three pool vertices, its
#: unit object-space normal (three float32, as their bits), two zeros. 32 bytes: a pixel's
#: face vertices and normal come in one cache line, not one line of each of two tables.
FACE_ROW_WORDS = 8

#: Triangles per box of the exact occlusion query: box b is faces 12b .. 12b+11 (triangle id
#: // 12 is the box; kernels/query.cl, reference/query.py box_geometry).
BOX_TRIS = 12

# ---- Lines -------------------------------------------------------------------------------

# Segment status codes (kernels/lines.cl, clraster.lines).
LS_ACCEPTED = 0  #: trivially accepted, rasterized
LS_CLIPPED = 1  #: clipped, something left, rasterized
LS_INVALID = 2  #: an endpoint (or its clip position) is NaN/Inf
LS_REJECTED = 3  #: trivially rejected: both endpoints outside one plane
LS_CLIPPED_AWAY = 4  #: clipped, nothing inside the view volume
LS_ACCEPTED_DEGENERATE = 5  #: trivially accepted, an endpoint at w < FLT_MIN
LS_CLIPPED_DEGENERATE = 6  #: clipped, an endpoint at w < FLT_MIN

#: Clear value of the lines' resolve buffers: zmin holds depth bits (non-negative floats order
#: like uints; all ones is above every depth, so a fragment at depth 1.0 still counts) and
#: idmin segment indices; all ones means "none" in both.
ZMIN_CLEAR = np.uint32(0xFFFFFFFF)
IDMIN_CLEAR = np.uint32(0xFFFFFFFF)

# ---- Records -----------------------------------------------------------------------------

#: One drawn (instance, cluster) pair (C ``Draw``). cluster: global cluster index in the
#: geometry pool; vert_base / tri_base: first vertex / triangle slot of the draw in this
#: frame's streams (the kernels have a triangle stream only: setup makes each draw's
#: vertices itself; the twin keeps a vertex stream); face_base: triangle id of the
#: instance's face 0; flags: DRAW_INSIDE, DRAW_MIRRORED, DRAW_NO_CLIP.
DRAW_DTYPE = np.dtype([("cluster", np.int32), ("instance", np.int32), ("vert_base", np.int32),
                       ("tri_base", np.int32), ("face_base", np.int32), ("flags", np.int32),
                       ("pad", np.int32, 2)])
assert DRAW_DTYPE.itemsize == 32

#: One triangle setup record, 96 bytes (C ``Piece``).
#: x, y: 24.8 fixed-point window coordinates (y down, row 0 at top), oriented so that the
#: window-space doubled area is > 0: coverage (edge functions, top-left rule) uses only these.
#: bb_min/bb_max: inclusive pixel range of the pixel centres in the bounding box, clamped to
#: the viewport, packed as x | y << 16. The values come from value planes set up in double
#: from the UNSNAPPED window positions (setup.cl `value_planes`), evaluated at pixel centres
#: relative to the reference pixel (px0, py0) = bb_min as fx = x − px0, fy = y − py0 (small
#: exact integers in float): window depth = (z0 + dzdy·fy) + dzdx·fx; screen-space weights
#: l_i = (l_i + l_ix·fx) + l_iy·fy for vertices 1, 2 (l_0 = 1 − l_1 − l_2). r1 = w0/w1,
#: r2 = w0/w2 give their perspective correction. zlo: the least window depth of the
#: piece's vertices; the raster raises interpolated depth to it, because a pixel centre that
#: the snapped coverage takes in may lie up to 1/512 px outside the unsnapped triangle,
#: where the depth plane extrapolates beyond its vertices without bound for steep triangles,
#: and culling (Hi-Z, pyramid.cl's error model) relies on no fragment being nearer than its
#: vertices. Only that side: a fragment extrapolated farther cannot make culling unsafe, and
#: every clamped pixel moves the value away from the ray caster's (tests/test_accuracy.py).
#: cover: for a box of at most 4 x 4 pixel centres, which of them the piece covers
#: (`COVER_KNOWN`; setup tests them anyway, and the raster then skips its edge functions);
#: 0 otherwise. pad: keeps the record 16-byte aligned.
PIECE_DTYPE = np.dtype([
    ("x", np.int32, 3), ("y", np.int32, 3),
    ("bb_min", np.int32), ("bb_max", np.int32),
    ("id", np.int32), ("flags", np.int32),
    ("z0", np.float32), ("dzdx", np.float32), ("dzdy", np.float32),
    ("l1", np.float32), ("l1x", np.float32), ("l1y", np.float32),
    ("l2", np.float32), ("l2x", np.float32), ("l2y", np.float32),
    ("r1", np.float32), ("r2", np.float32), ("zlo", np.float32), ("cover", np.int32),
    ("pad", np.int32),
])
assert PIECE_DTYPE.itemsize == 96

#: A vertex after the viewport transform (C ``WinVert``): 24.8 fixed-point window x, y
#: (y down), window depth z = (z/w + 1)/2 and iw = 1/w.
WINVERT_DTYPE = np.dtype([("x", np.int32), ("y", np.int32), ("z", np.float32),
                          ("iw", np.float32)])

#: A vertex of the frame's vertex stream after the viewport transform (an ``int2`` in the
#: kernels, common.h ``win_xy``): 24.8 fixed-point window x, y (y down), all that setup
#: reads of it (half of a 16-byte WinVert: less memory traffic in vertex and setup).
WINXY_DTYPE = np.dtype([("x", np.int32), ("y", np.int32)])

#: One set-up line segment (C ``LineRec``), 32 bytes: 24.8 fixed-point window endpoints in
#: canonical order along the major axis (xs/ys the start), the start's window depth zs and
#: (end − start) depth dz. Only status (LS_*) is meaningful unless status is LS_ACCEPTED or
#: LS_CLIPPED.
LINE_DTYPE = np.dtype([("xs", np.int32), ("ys", np.int32), ("xe", np.int32), ("ye", np.int32),
                       ("zs", np.float32), ("dz", np.float32), ("status", np.int32),
                       ("pad", np.int32)])
assert LINE_DTYPE.itemsize == 32

# ---- What the kernels get ----------------------------------------------------------------

#: Every constant the kernels see, as (comment, names) groups, in header order. Each name is
#: a module attribute here and a ``#define`` of the same name in C.
C_DEFINES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("24.8 fixed point: vertices snap to 1/256 pixel", ("SUBPIXEL_BITS",)),
    ("Outcode bits (vertex stage). Bits 0..5 are the classic 6-bit frustum outcode; 6..9 say "
     "the vertex is outside the guard band (x/y clipping needed); bit 10 marks NaN/Inf; "
     "OC_W_NONPOS: w <= 0, no window position (never set alone on a drawn vertex)",
     ("OC_X_NEG", "OC_X_POS", "OC_Y_NEG", "OC_Y_POS", "OC_Z_NEG", "OC_Z_POS", "OC_FRUSTUM",
      "OC_GB_X_NEG", "OC_GB_X_POS", "OC_GB_Y_NEG", "OC_GB_Y_POS", "OC_INVALID", "OC_W_NONPOS",
      "OC_NEEDS_CLIP")),
    ("Per-triangle status (triangle setup)",
     ("ST_RASTER", "ST_CLIPPED", "ST_INVALID", "ST_TRIVIAL_REJECT", "ST_BACKFACE",
      "ST_DEGENERATE", "ST_NO_SAMPLE")),
    ("Piece flags; clipped pieces: flags >> PF_INDEX_SHIFT = index into the clipped-bary buffer",
     ("PF_SWAPPED", "PF_CLIPPED", "PF_INDEX_SHIFT")),
    ("Piece.cover: the coverage bits of a box of at most COVER_SPAN x COVER_SPAN pixel centres "
     "are known", ("COVER_SPAN", "COVER_KNOWN")),
    ("Cull modes", ("CULL_NONE", "CULL_BACK", "CULL_FRONT")),
    ("Clipping: user clip planes; vertices of a clipped triangle and of the clipper's polygon",
     ("USER_PLANES_MAX", "MAX_CLIP_VERTICES", "POLY_MAX")),
    ("Clusters (meshlets): at most CLUSTER_MAX triangles and vertices; draw flags",
     ("CLUSTER_LOG2", "CLUSTER_MAX", "VERTEX_LANES", "SETUP_LANES", "DRAW_INSIDE",
      "DRAW_MIRRORED", "DRAW_NO_CLIP")),
    ("Depth pyramid: levels per launch; Hi-Z test results and error model (pyramid.cl)",
     ("PYR_LOG2", "OCC_VISIBLE", "OCC_OCCLUDED", "OCC_VIEW_CULLED", "HIZ_EPS",
      "HIZ_DEPTH_SLACK", "HIZ_PIXEL_SLACK")),
    ("Exact occlusion queries: triangles per box", ("BOX_TRIS",)),
    ("Resolve and shading: words of a face row (pool vertices a b c, normal x y z as float "
     "bits, 2 zeros)", ("FACE_ROW_WORDS",)),
    ("Line segment status; clear value of the lines' resolve buffers",
     ("LS_ACCEPTED", "LS_CLIPPED", "LS_INVALID", "LS_REJECTED", "LS_CLIPPED_AWAY",
      "LS_ACCEPTED_DEGENERATE", "LS_CLIPPED_DEGENERATE", "ZMIN_CLEAR", "IDMIN_CLEAR")),
)

#: Every record the kernels see: C struct name -> name of its dtype here, in header order.
C_RECORDS: dict[str, str] = {
    "Piece": "PIECE_DTYPE",
    "Draw": "DRAW_DTYPE",
    "WinVert": "WINVERT_DTYPE",
    "LineRec": "LINE_DTYPE",
}

_C_TYPES = {
    np.dtype(np.int8): "char", np.dtype(np.uint8): "uchar",
    np.dtype(np.int16): "short", np.dtype(np.uint16): "ushort",
    np.dtype(np.int32): "int", np.dtype(np.uint32): "uint",
    np.dtype(np.int64): "long", np.dtype(np.uint64): "ulong",
    np.dtype(np.float32): "float", np.dtype(np.float64): "double",
}

#: The line of kernels/common.h that `inline_layout` replaces with `c_header()`.
LAYOUT_INCLUDE = re.compile(r'^#include "layout\.h".*$', re.M)


def c_literal(value: object) -> str:
    """C literal of a constant: Python int -> decimal, np.uint32 -> hex with ``u``,
    np.float32 -> its shortest round-trip decimal with ``f`` (exact: the value is a float32)."""
    if isinstance(value, np.uint32):
        return f"0x{int(value):X}u"
    if isinstance(value, np.float32):
        text = repr(float(value))
        assert np.float32(text) == value and ("." in text or "e" in text), text
        return text + "f"
    if isinstance(value, int) and not isinstance(value, bool) and -2**31 <= value < 2**31:
        return str(value)
    raise TypeError(f"no C literal for {value!r} ({type(value).__name__}); use a Python int, "
                    f"np.uint32 or np.float32")


def c_struct(name: str, dtype: np.dtype) -> str:
    """``typedef struct { ... } name;`` with the fields of ``dtype``, in order.

    Raises ValueError when the dtype's packed layout is not what a C compiler would give it
    (a gap, a field off its natural alignment, trailing padding, unknown or nested types)."""
    lines = []
    offset, largest = 0, 1
    fields = cast("Mapping[str, tuple[np.dtype, int]]", dtype.fields)   # a structured dtype
    for field in cast("tuple[str, ...]", dtype.names):
        fdt, at = fields[field][:2]
        base, shape = fdt.subdtype if fdt.subdtype else (fdt, ())
        if base not in _C_TYPES or len(shape) > 1:
            raise ValueError(f"{name}.{field}: dtype {fdt} has no C equivalent here")
        if at != offset or offset % base.itemsize:
            raise ValueError(f"{name}.{field} at offset {at}: fields must follow each other "
                             f"with no gap, each at a multiple of its scalar size "
                             f"({base.itemsize}), as a C compiler would place them")
        offset += fdt.itemsize
        largest = max(largest, base.itemsize)
        dims = f"[{shape[0]}]" if shape else ""
        lines.append(f"    {_C_TYPES[base]} {field}{dims};")
    if dtype.itemsize != offset or offset % largest:
        raise ValueError(f"{name}: {dtype.itemsize} bytes does not end where a C struct of "
                         f"these fields would ({offset} rounded up to {largest})")
    return "typedef struct {\n" + "\n".join(lines) + f"\n}} {name};"


def c_header() -> str:
    """The generated part of kernels/common.h: every `C_DEFINES` constant and `C_RECORDS`
    struct, with a comment per group."""
    g = globals()
    out = ["/* ---- Generated by clraster.base.layout.c_header() from clraster/base/layout.py; "
           "edit the values there. ---- */"]
    for comment, names in C_DEFINES:
        out.append("/* " + "\n * ".join(textwrap.wrap(comment + ". */", 93)))
        out.extend(f"#define {n} {c_literal(g[n])}" for n in names)
    for name, var in C_RECORDS.items():
        out.append(f"/* clraster.base.layout.{var}, {g[var].itemsize} bytes. */")
        out.append(c_struct(name, g[var]))
    out.append("/* ---- End of generated part. ---- */")
    return "\n".join(out) + "\n"


def inline_layout(common_h: str) -> str:
    """kernels/common.h text with its ``#include "layout.h"`` line replaced by `c_header`."""
    text, n = LAYOUT_INCLUDE.subn(lambda _m: c_header().rstrip("\n"), common_h, count=1)
    if n != 1:
        raise ValueError('kernels/common.h has no `#include "layout.h"` line for the '
                         'generated constants (clraster.base.layout.c_header)')
    return text
