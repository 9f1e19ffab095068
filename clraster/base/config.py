"""Every tunable of the pipeline, in one place.

`RasterConfig` is a frozen dataclass: it is hashed into the program cache key and turned into
the ``-D`` options that the kernels in ``kernels/`` are built with. The NumPy twin reads the
same object, so both sides agree on every constant.

Constants that are *rules*, not tunables (they are part of the output contract and never
change the image when a tunable does):

* ``SUBPIXEL_BITS = 8``: vertices snap to 1/256 pixel, as D3D11 requires. Like every
  constant and record the kernels share with the host (outcode bits, status codes, piece
  flags, PIECE_DTYPE...), it is defined in `clraster.base.layout`, which generates the kernels'
  copies, and re-exported here.
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

# The constants and records shared with the kernels live in clraster/layout.py, their one
# source (it generates the kernels' #defines and structs); they are re-exported here, where
# the pipeline has always imported them from.
from .layout import (
    CLUSTER_LOG2,
    CLUSTER_MAX,
    COVER_KNOWN,
    CULL_MODES,
    DRAW_DTYPE,
    DRAW_INSIDE,
    MAX_CLIP_VERTICES,
    OC_FRUSTUM,
    OC_GB_X_NEG,
    OC_GB_X_POS,
    OC_GB_Y_NEG,
    OC_GB_Y_POS,
    OC_INVALID,
    OC_NEEDS_CLIP,
    OC_W_NONPOS,
    OC_X_NEG,
    OC_X_POS,
    OC_Y_NEG,
    OC_Y_POS,
    OC_Z_NEG,
    OC_Z_POS,
    PF_CLIPPED,
    PF_INDEX_SHIFT,
    PF_SWAPPED,
    PIECE_DTYPE,
    ST_BACKFACE,
    ST_CLIPPED,
    ST_DEGENERATE,
    ST_INVALID,
    ST_NO_SAMPLE,
    ST_RASTER,
    ST_TRIVIAL_REJECT,
    STATUS_NAMES,
    SUBPIXEL_BITS,
    SUBPIXEL_ONE,
    WINVERT_DTYPE,
    WINXY_DTYPE,
)

__all__ = [
    "CLUSTER_LOG2", "CLUSTER_MAX", "COVER_KNOWN", "CULL_MODES", "DRAW_DTYPE", "DRAW_INSIDE",
    "GUARD_BAND_PIXELS", "MAX_CLIP_VERTICES", "MAX_IMAGE_SIZE", "OC_FRUSTUM", "OC_GB_X_NEG",
    "OC_GB_X_POS", "OC_GB_Y_NEG", "OC_GB_Y_POS", "OC_INVALID", "OC_NEEDS_CLIP", "OC_W_NONPOS",
    "OC_X_NEG", "OC_X_POS", "OC_Y_NEG", "OC_Y_POS", "OC_Z_NEG", "OC_Z_POS", "PF_CLIPPED",
    "PF_INDEX_SHIFT", "PF_SWAPPED", "PIECE_DTYPE", "ST_BACKFACE", "ST_CLIPPED", "ST_DEGENERATE",
    "ST_INVALID", "ST_NO_SAMPLE", "ST_RASTER", "ST_TRIVIAL_REJECT", "STATUS_NAMES",
    "SUBPIXEL_BITS", "SUBPIXEL_ONE", "WINVERT_DTYPE", "WINXY_DTYPE", "RasterConfig",
    "guard_band_factors",
]

MAX_IMAGE_SIZE = 16384
GUARD_BAND_PIXELS = 1 << 19


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
        batch_triangles: a frame's draws go through the stage chain (vertex → setup →
            bin → raster) in consecutive batches of at most this many triangles, each
            rasterized into the same frame buffers (`clraster.pipeline.streaming`), so the vertex,
            setup and bin buffers are sized by the batch, never by the scene: at most 346
            bytes per triangle of the budget (`StageChain.budget_bounds`: draw records,
            the vertex stream of three vertices, the setup record, status and tile words,
            the list of slots to bin). A draw (one
            cluster, ≤ CLUSTER_MAX triangles) is the smallest unit, so values below
            CLUSTER_MAX are refused. Never changes the image or the counts. Each extra pass
            costs a few launches and waits, and the raster reloads the tiles it touches.
            Default ``1 << 20``, measured (bench/README.md, "Streamed frames"): at 1920×1080
            2**16 was clearly slower (dragon min 203 vs 106 ms; 5M plant outside 1418 vs
            1041–1120 ms), 2**18 a little slower, 2**20 and 2**22 alike within the noise;
            2**20 keeps the dragon (871K triangles) in one pass and bounds these buffers to
            ~346 MiB (207 MiB with the 64-byte records and float32 vertex stream this was
            measured with), where 2**22 held 642 MiB on the plant.
        batch_entries: the (piece, tile) entries of one pass's bin list, at most (clipped
            pieces count against it too). A batch whose count step finds more is split and
            drawn again in smaller batches (never truncated, never refused); a single draw
            larger than this still goes through alone, and the buffers it grew are released
            after the frame. Memory: 96 bytes per entry (the entries are copies of the
            96-byte setup records, which the raster reads sequentially) plus 132 per
            clipped piece. Default ``1 << 21`` (192 MiB of entries): ordinary scenes bin
            ~0.5 entries per triangle (dragon 0.46, 5M plant 0.56 at 1080p), so a full
            triangle batch needs ~2**19 and this never binds there (2**20..2**22 measured
            alike); it splits only frames of huge overlapping triangles, whose passes are
            raster work anyway. 2**22 would double the bound for no measured gain.
        tile_hiz: the raster skips a piece whose nearest depth is behind the farthest
            depth its tile holds at that moment (kernels/raster.cl): it could pass nowhere
            there. Never changes the image; it lowers ``fragments_tested`` and the overdraw
            map, which then count the fragments that reached the depth test (without it,
            every covered fragment, the scene's depth complexity). The twin takes the same
            decisions. 10M plant first person with occlusion culling: 12.2M fragments
            tested → 7.2M, raster 0.74×; no gain where back-face culling leaves little
            overdraw (dragon, bunny, spot framed: tested ≈ passed), dragon raster ~1.02×.
        occlusion_groups: hierarchical occlusion culling (`clraster.pipeline.twophase`): after the
            first frame, each instance's clusters are taken in groups of at most this many
            (neighbours in its mesh's cluster BVH; a small mesh's instance is one group),
            the groups' world boxes are Hi-Z tested first, and only the clusters of the
            groups not proved hidden are frustum-, cone- and Hi-Z tested one by one. Never
            changes the image; the counts then say "occlusion culled" for clusters whose
            group was hidden, where the flat scheme (0: every cluster that survives the
            frustum and cone tests is Hi-Z tested) would have counted some of them
            frustum- or cone-culled first. Default 16 (10M plant first person: 8.2K of
            106K clusters left to test one by one; frame medians with groups of 16 / 32 /
            64: 44.5 / 45.2 / 46.2 ms in one run, of 8 / 12 / 16 / 24: 45.1 / 44.9 / 44.8 /
            45.3 in another, ~52 flat; bench/README.md).
    """

    tile_log2: int = 4
    bin_chunks: int = 64
    batch_triangles: int = 1 << 20
    batch_entries: int = 1 << 21
    tile_hiz: bool = True
    occlusion_groups: int = 16

    def __post_init__(self) -> None:
        if not 3 <= self.tile_log2 <= 6:
            raise ValueError(f"tile_log2 must be in 3..6 (8..64 px tiles), got {self.tile_log2}")
        if not 1 <= self.bin_chunks <= 4096:
            raise ValueError(f"bin_chunks must be in 1..4096, got {self.bin_chunks}")
        for name, lo in (("batch_triangles", CLUSTER_MAX), ("batch_entries", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) \
                    or not lo <= v < 2**31:
                raise ValueError(f"{name} must be an integer in {lo}..2**31 - 1, got {v!r}")
        if not isinstance(self.tile_hiz, (bool, np.bool_)):
            raise ValueError(f"tile_hiz must be True or False, got {self.tile_hiz!r}")
        g = self.occlusion_groups
        if isinstance(g, bool) or not isinstance(g, (int, np.integer)) or not 0 <= g <= 1 << 20:
            raise ValueError(f"occlusion_groups must be an integer in 0..2**20 (0: no "
                             f"groups), got {g!r}")

    @property
    def tile_size(self) -> int:
        return 1 << self.tile_log2

    def tiles(self, width: int, height: int) -> tuple[int, int]:
        """Number of tiles (x, y) covering a width × height image."""
        t = self.tile_size
        return (width + t - 1) // t, (height + t - 1) // t

    def build_options(self) -> tuple[str, ...]:
        """The ``-D`` options the kernels are built with (the tunables; the fixed constants
        reach the kernels through clraster.base.layout's generated header)."""
        return (f"-DTILE_LOG2={self.tile_log2}",)


def guard_band_factors(width: int, height: int) -> tuple[np.float32, np.float32]:
    """Clip-space guard-band factors (kx, ky): x/y clipping planes are ±k·w.

    Chosen so that window coordinates stay within ±GUARD_BAND_PIXELS of the origin:
    x_win = (x/w + 1) · W/2, so |x/w| ≤ 2·G/W − 1 keeps |x_win| ≤ G.
    """
    kx = np.float32(2.0 * GUARD_BAND_PIXELS / width - 1.0)
    ky = np.float32(2.0 * GUARD_BAND_PIXELS / height - 1.0)
    return kx, ky
