"""Every tunable of the pipeline, in one place.

`RasterConfig` is a frozen dataclass: it is hashed into the program cache key and turned into
the ``-D`` options that the kernels in ``kernels/`` are built with. The NumPy twin reads the
same object, so both sides agree on every constant.

Constants that are *rules*, not tunables (they are part of the output contract and never
change the image when a tunable does):

* ``SUBPIXEL_BITS = 8``: vertices snap to 1/256 pixel, as D3D11 requires.
* ``MAX_IMAGE_SIZE = 16384``: widths/heights above this are refused. Pixel coordinates are
  packed into 16 bits in the triangle setup records (``Piece.bb_min``/``bb_max``).
* ``GUARD_BAND_PIXELS = 2**19``: window coordinates of any vertex that reaches the fixed-point
  snap lie within ±2**19 pixels of the viewport centre (clip-space x/y clipping happens only
  for triangles that leave this band). In 24.8 fixed point that is ±2**27, so edge-function
  differences fit 2**28 and their products (64-bit) 2**57: exact, with headroom.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SUBPIXEL_BITS = 8
SUBPIXEL_ONE = 1 << SUBPIXEL_BITS
MAX_IMAGE_SIZE = 16384
GUARD_BAND_PIXELS = 1 << 19
#: Triangles clipped by near, far and 4 guard-band planes have at most 3 + 6 vertices.
MAX_CLIP_VERTICES = 9

# Outcode bits written by the vertex stage (kernels/common.h mirrors these).
OC_X_NEG, OC_X_POS, OC_Y_NEG, OC_Y_POS, OC_Z_NEG, OC_Z_POS = 1, 2, 4, 8, 16, 32
OC_FRUSTUM = 63
OC_GB_X_NEG, OC_GB_X_POS, OC_GB_Y_NEG, OC_GB_Y_POS = 64, 128, 256, 512
OC_INVALID = 1024
OC_W_NONPOS = 2048  #: w <= 0: the vertex has no window position
#: Planes that force a triangle through the clipper: near, far and the four guard-band planes.
OC_NEEDS_CLIP = OC_Z_NEG | OC_Z_POS | OC_GB_X_NEG | OC_GB_X_POS | OC_GB_Y_NEG | OC_GB_Y_POS

# Per-triangle status written by triangle setup (kernels/common.h mirrors these).
ST_RASTER = 0  #: unclipped, one setup record at its own slot, sent to binning
ST_CLIPPED = 1  #: went through the clipper; 0..7 pieces in the clipped-piece buffer
ST_INVALID = 2  #: a vertex is NaN/Inf (or its clip position is): dropped and counted
ST_TRIVIAL_REJECT = 3  #: all three vertices outside one frustum plane
ST_BACKFACE = 4  #: culled by the cull mode
ST_DEGENERATE = 5  #: zero area after the fixed-point snap
ST_NO_SAMPLE = 6  #: bounding box holds no pixel centre: covers nothing (exact, not a guess)
STATUS_NAMES = ("raster", "clipped", "invalid", "trivial_reject", "backface", "degenerate",
                "no_sample")

# Piece flags.
PF_SWAPPED = 1  #: vertices 1 and 2 were swapped to make the window-space area positive
PF_CLIPPED = 2  #: made by the clipper; parent barycentrics live in the clipped-bary buffer
PF_INDEX_SHIFT = 2  #: clipped pieces: flags >> 2 is their index in the clipped-bary buffer

CULL_MODES = {"none": 0, "back": 1, "front": 2}

#: Clusters (meshlets) have at most CLUSTER_MAX triangles and CLUSTER_MAX vertices; the vertex
#: and setup kernels run one work-item per (draw, local index) (kernels/common.h).
CLUSTER_LOG2 = 7
CLUSTER_MAX = 1 << CLUSTER_LOG2
DRAW_INSIDE = 1  #: draw flag: cluster inside the frustum by a margin, no clip tests needed

#: One drawn (instance, cluster) pair; mirrors `Draw` in kernels/common.h. cluster: global
#: cluster index in the geometry pool; vert_base / tri_base: first vertex / triangle slot of
#: the draw in this frame's streams; face_base: triangle id of the instance's face 0.
DRAW_DTYPE = np.dtype([("cluster", np.int32), ("instance", np.int32), ("vert_base", np.int32),
                       ("tri_base", np.int32), ("face_base", np.int32), ("flags", np.int32),
                       ("pad", np.int32, 2)])
assert DRAW_DTYPE.itemsize == 32

#: One triangle setup record, 64 bytes (one cache line). Mirrors `Piece` in kernels/common.h.
#: x, y: 24.8 fixed-point window coordinates (y down, row 0 at top), oriented so that the
#: window-space doubled area is > 0. bb_min/bb_max: inclusive pixel range of the pixel centres
#: in the bounding box, clamped to the viewport, packed as x | y << 16. Depth at a pixel is
#: z0 + l1*dz10 + l2*dz20 with l_i = E_i * inv_area. r1 = w0/w1, r2 = w0/w2 give the
#: perspective correction of the piece's screen-space weights.
PIECE_DTYPE = np.dtype([
    ("x", np.int32, 3), ("y", np.int32, 3),
    ("bb_min", np.int32), ("bb_max", np.int32),
    ("z0", np.float32), ("dz10", np.float32), ("dz20", np.float32), ("inv_area", np.float32),
    ("id", np.int32), ("flags", np.int32), ("r1", np.float32), ("r2", np.float32),
])
assert PIECE_DTYPE.itemsize == 64

#: A vertex after the viewport transform (kernels/common.h WinVert): 24.8 fixed-point window
#: x, y (y down), window depth z = (z/w + 1)/2 and iw = 1/w.
WINVERT_DTYPE = np.dtype([("x", np.int32), ("y", np.int32), ("z", np.float32),
                          ("iw", np.float32)])


@dataclass(frozen=True)
class RasterConfig:
    """Tunables of the OpenCL pipeline. None of them changes the output image.

    Attributes:
        tile_log2: screen tiles are ``1 << tile_log2`` pixels square (3..6: 8..64 px).
            Smaller tiles bin more entries; larger ones keep more per-tile state in
            private memory (64×64 = 32 KiB per work-item) and balance worse on few cores.
        bin_chunks: the triangle stream is cut into this many contiguous chunks for
            binning; each chunk counts and scatters its own triangles per tile, so the
            per-tile lists keep submission order with no atomics. Memory is
            ``bin_chunks × tiles × 4`` bytes.
    """

    tile_log2: int = 4
    bin_chunks: int = 64

    def __post_init__(self) -> None:
        if not 3 <= self.tile_log2 <= 6:
            raise ValueError(f"tile_log2 must be in 3..6 (8..64 px tiles), got {self.tile_log2}")
        if not 1 <= self.bin_chunks <= 4096:
            raise ValueError(f"bin_chunks must be in 1..4096, got {self.bin_chunks}")

    @property
    def tile_size(self) -> int:
        return 1 << self.tile_log2

    def tiles(self, width: int, height: int) -> tuple[int, int]:
        """Number of tiles (x, y) covering a width × height image."""
        t = self.tile_size
        return (width + t - 1) // t, (height + t - 1) // t

    def build_options(self) -> tuple[str, ...]:
        """The ``-D`` options the kernels are built with."""
        return (f"-DTILE_LOG2={self.tile_log2}", f"-DSUBPIXEL_BITS={SUBPIXEL_BITS}")


def guard_band_factors(width: int, height: int) -> tuple[np.float32, np.float32]:
    """Clip-space guard-band factors (kx, ky): x/y clipping planes are ±k·w.

    Chosen so that window coordinates stay within ±GUARD_BAND_PIXELS of the origin:
    x_win = (x/w + 1) · W/2, so |x/w| ≤ 2·G/W − 1 keeps |x_win| ≤ G.
    """
    kx = np.float32(2.0 * GUARD_BAND_PIXELS / width - 1.0)
    ky = np.float32(2.0 * GUARD_BAND_PIXELS / height - 1.0)
    return kx, ky
