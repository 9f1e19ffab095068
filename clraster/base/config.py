"""Every tunable of the pipeline, in one place.

Two kinds, both for speed or memory only: none of them changes an image or an id (a few
change how the culling counts attribute a culled cluster, as their comments say):

* `RasterConfig`: the per-renderer tunables, a frozen dataclass. It is hashed into the
  program cache key and turned into the ``-D`` options the kernels in ``kernels/`` are built
  with (`RasterConfig.build_options`); the NumPy twin reads the same object.
* Module constants below: fixed tunables, one line each with its effect, unit and limits
  (as nvdiffrast's ``Constants.hpp``). Those in `KERNEL_TUNABLES` reach the kernels as
  ``-D`` options too (no kernel file spells them out); the others are read by the host
  module named in their comment, which imports them by name (tests and benchmarks switch
  them there, on that module).

Constants that are *rules*, not tunables (part of the output contract): the fixed point
(``SUBPIXEL_BITS = 8``: vertices snap to 1/256 pixel, as D3D11 requires), outcode bits,
status codes, piece flags and records live in `clraster.base.layout`, which generates the
kernels' copies; import them from there. Two more rules are here, since the host's checks
use them:

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

from .layout import CLUSTER_MAX

__all__ = [
    "CLEAR_SHARES", "CLIP_SCRATCH_BYTES", "CLIP_TEST_DRAWS", "CLUSTER_LEAF_SIZE",
    "DENSE_CHUNK", "DENSE_CLUSTERS", "DENSE_INSTANCES", "DENSE_PAIRS",
    "FLAT_CLUSTERS", "FLAT_MAX_PAIRS", "GUARD_BAND_PIXELS", "HIZ_TEST_LOCAL",
    "KERNEL_TUNABLES", "LINES_LOCAL", "MAX_IMAGE_SIZE", "MIN_CHUNK_TRIANGLES",
    "OCCLUSION_FIRST_CLUSTERS", "QUERY_SPAN", "SCAN_CHUNKS", "SEG_PIXELS", "THREAD_PAIRS",
    "TRIM_ROWS", "WIDE_RUN", "RasterConfig", "guard_band_factors",
]

# ---- Rules the host checks (module docstring) ----------------------------------------------

MAX_IMAGE_SIZE = 16384
GUARD_BAND_PIXELS = 1 << 19

# ---- Kernel tunables (-D options of every program; speed only) ----------------------------

#: raster.cl: a piece spanning at least this many columns of a tile (x1 - x0 >= WIDE_RUN)
#: finds each row's covered run by division (edge_columns); a narrower one tests its edges
#: in lanes of eight. Pixels; any value >= 0 gives the same fragments.
WIDE_RUN = 8
#: raster.cl: a piece over at least this many rows of a tile (y1 - y0 >= TRIM_ROWS) first
#: narrows its rows to those its edges can meet. Rows; any value >= 0.
TRIM_ROWS = 4
#: query.cl: columns per branch-free span of the occlusion query's pixel loop. Pixels; a
#: power of two <= 8 (it must divide every tile size, 8..64).
QUERY_SPAN = 8
#: The constants above, in the order `RasterConfig.build_options` passes them.
KERNEL_TUNABLES = ("WIDE_RUN", "TRIM_ROWS", "QUERY_SPAN")

# ---- Launch shapes (host stages; speed only) -----------------------------------------------

#: stages/raster.py: pixels of a row of tiles per raster work-item, about (a row of tiles is
#: cut into segments of this many pixels' worth of whole tiles, at least one). Pixels;
#: >= 1. Narrower: more work-items, shorter runs of empty tiles to clear; wider: fewer
#: work-items, which leave a core idle when the work sits in a few rows (the plant seen
#: from inside: 16 px tiles in 256 px segments balanced, 64 px tiles in 1024 px segments did
#: not; bench/README.md).
SEG_PIXELS = 128
#: stages/raster.py: contiguous shares of a cleared frame (`RasterStage.clear`, kernel
#: clear_frame) per compute unit. >= 1; a few, so that a core the host's thread holds for a
#: moment leaves its shares to the others.
CLEAR_SHARES = 4
#: stages/setup.py: ranges of the clip-count scan, one work-item each. >= 1; a few per core.
SCAN_CHUNKS = 64
#: stages/setup.py: the clipped triangles of a pass are clipped once, into scratch rows of as
#: many pieces as one triangle can give (7 + the clipping user planes, 132 bytes each),
#: while those rows take at most this much; more are clipped twice, counting first (the
#: scratch would be as big as the pass's triangles times ~1 KB). Bytes; 0: always twice.
CLIP_SCRATCH_BYTES = 64 << 20
#: stages/bin.py: fewest triangles per bin chunk (RasterConfig.bin_chunks caps the count).
#: Triangles; >= 1. The per-chunk rows of tile counts are a fixed cost per chunk that small
#: meshes would otherwise pay 64 times.
MIN_CHUNK_TRIANGLES = 1024
#: stages/pyramid.py: work-group size of the Hi-Z box test (one work-item per 8 boxes).
#: Work-items; >= 1 (PoCL compiles one specialization per local size).
HIZ_TEST_LOCAL = 16
#: stages/lines.py: work-group size of the three line kernels. Work-items; >= 1.
LINES_LOCAL = 64

# ---- Host culling paths (culling/cull.py; speed only: every path gives the same answer) ----

#: Clusters per leaf of a mesh's cluster BVH. >= 1.
CLUSTER_LEAF_SIZE = 32
#: Instances of meshes with at most this many clusters take the flat path: their (instance,
#: cluster) boxes are precomputed in world space and tested all at once. Clusters.
FLAT_CLUSTERS = 64
#: ... unless the scene has more such pairs than this (84 bytes each, kept with the scene).
FLAT_MAX_PAIRS = 1 << 21
#: Meshes with at most this many (bounded) clusters are tested densely, every cluster
#: against every intersecting instance's planes (three matrix products), not through their
#: BVH: for small meshes with many instances that is several times faster. Clusters.
DENSE_CLUSTERS = 64
#: ... and so are meshes whose (instances × clusters) grid is at most this large. Pairs.
DENSE_PAIRS = 16384
#: (instance, cluster) pairs per batch of the dense test: bounds its temporaries. >= 1.
DENSE_CHUNK = 1 << 18
#: Scenes with at most this many bounded instances classify them densely, every instance box
#: against the planes, not through the instance BVH (whose traversal pays off when whole
#: subtrees are culled among many more instances). Instances.
DENSE_INSTANCES = 1 << 15
#: Below this many (instance, cluster) pairs to look at, the culling paths run one after the
#: other in the calling thread; above, on helper threads. Pairs; 0: always threads.
THREAD_PAIRS = 32768
#: A frame's draws that are not INSIDE the frustum are tested for clipping on the host
#: (`clraster.culling.cull.ViewCull.clip_free`: DRAW_NO_CLIP) while there are at most this
#: many of them; a pass whose draws all need no clipping skips the wait for setup's clip
#: count. Above it the test costs more than the wait saves. Draws; 0: never tested.
CLIP_TEST_DRAWS = 4096

# ---- Occlusion culling (pipeline/twophase.py) ----------------------------------------------

#: First frame of occlusion culling: at least this many of the nearest clusters (or 1/8 of
#: those that survive frustum culling, if more) are drawn before the first pyramid. Clusters;
#: >= 0. Changes which clusters the counts call occlusion-culled, never the image.
OCCLUSION_FIRST_CLUSTERS = 256


@dataclass(frozen=True)
class RasterConfig:
    """Tunables of the OpenCL pipeline. None of them changes the output image.

    Attributes:
        tile_log2: screen tiles are ``1 << tile_log2`` pixels square (3..6: 8..64 px).
            Smaller tiles bin more entries (a piece goes to every tile its edges reach) and
            pay the per-tile set-up more often; larger ones keep more per-tile state in
            private memory (64 KiB per raster work-item at 64 × 64: depth, winner, id and
            overdraw per pixel). Default 6 (64 px): on PoCL (pip and distribution builds)
            the fastest on every scene of the benchmark (the 10M plant seen from inside
            0.78× the frame time of 16 px tiles, the dragon at 1080p 0.95×); Intel's CPU
            runtime, which runs work-items in SIMD lanes each with its own tile state,
            rasterizes small triangles faster at 16 px (bench/README.md).
        bin_chunks: the triangle stream is cut into this many contiguous chunks for
            binning; each chunk counts and scatters its own triangles per tile, so the
            per-tile lists keep submission order with no atomics. Memory is
            ``bin_chunks × tiles × 4`` bytes.
        batch_triangles: a frame's draws go through the stage chain (setup, with the
            vertex transform → bin → raster) in consecutive batches of at most this many
            triangles, each rasterized into the same frame buffers
            (`clraster.pipeline.streaming`), so the setup and bin buffers are sized by the
            batch, never by the scene: at most 153 bytes per triangle of the budget
            (`StageChain.budget_bounds`: draw records, the setup record, status and tile
            words, the list of clipped triangles, the list of slots to bin). A draw (one
            cluster, ≤ CLUSTER_MAX triangles) is the smallest unit, so values below
            CLUSTER_MAX are refused. Never changes the image or the counts. Each extra pass
            costs a few launches and waits, and the raster reloads the tiles it touches.
            Default ``1 << 20`` (153 MiB of these buffers): the dragon (871K triangles) in
            one pass; smaller budgets were slower, larger ones no faster (bench/README.md,
            "Streamed frames").
        batch_entries: the (piece, tile) entries of one pass's bin list, at most (clipped
            pieces count against it too). A batch whose count step finds more is split and
            drawn again in smaller batches (never truncated, never refused); a single draw
            larger than this still goes through alone, and the buffers it grew are released
            after the frame. Memory: 96 bytes per entry (the entries are copies of the
            96-byte setup records, which the raster reads sequentially) plus 132 per
            clipped piece. Default ``1 << 21`` (192 MiB of entries): ordinary scenes bin
            ~0.5 entries per triangle, so a full triangle batch needs ~2**19 and this never
            binds there; it splits only frames of huge overlapping triangles, whose passes
            are raster work anyway.
        tile_hiz: the raster skips a piece whose nearest depth is behind the farthest
            depth its tile holds at that moment (kernels/raster.cl): it could pass nowhere
            there. Never changes the image; it lowers ``fragments_tested`` and the overdraw
            map, which then count the fragments that reached the depth test (without it,
            every covered fragment, the scene's depth complexity). The twin takes the same
            decisions. It pays where overdraw survives culling (the plant seen from
            inside); where back-face culling leaves little overdraw it neither gains nor
            costs.
        occlusion_groups: hierarchical occlusion culling (`clraster.pipeline.twophase`):
            after the first frame, each instance's clusters are taken in groups of at most
            this many (neighbours in its mesh's cluster BVH; a small mesh's instance is one
            group), the groups' world boxes are Hi-Z tested first, and only the clusters of
            the groups not proved hidden are frustum-, cone- and Hi-Z tested one by one.
            Never changes the image; the counts then say "occlusion culled" for clusters
            whose group was hidden, where the flat scheme (0: every cluster that survives
            the frustum and cone tests is Hi-Z tested) would have counted some of them
            frustum- or cone-culled first. Default 16: 8 to 64 measured alike, all faster
            than flat (bench/README.md).
        views_in_flight: many views of one target (`Renderer.render_many`,
            `clraster.batch.iter_views` and `render_views`) are rendered this many at a
            time, each by its own renderer on this device in a thread of its own, and
            handed out in order, so that one view's host work (culling, planning, the
            caller's own use of the last frame) runs while the device draws another. 1 or
            2. Used only where it pays: camera lists or files (read ahead; other iterables
            one camera per view), a target that one pass draws (at most
            ``batch_triangles`` triangles: the second renderer holds its own pass buffers
            and copy of the scene's geometry on the device, as much again as the first's),
            and no occlusion culling (whose history is the view drawn just before). Never
            changes a frame. Default 2: +10% views/s on the dragon's 640 × 480 datasets
            job (bench/README.md, "Views in flight").
    """

    tile_log2: int = 6
    bin_chunks: int = 64
    batch_triangles: int = 1 << 20
    batch_entries: int = 1 << 21
    tile_hiz: bool = True
    occlusion_groups: int = 16
    views_in_flight: int = 2

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
        v = self.views_in_flight
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v not in (1, 2):
            raise ValueError(f"views_in_flight must be 1 or 2, got {v!r}")

    @property
    def tile_size(self) -> int:
        return 1 << self.tile_log2

    def tiles(self, width: int, height: int) -> tuple[int, int]:
        """Number of tiles (x, y) covering a width × height image."""
        t = self.tile_size
        return (width + t - 1) // t, (height + t - 1) // t

    def build_options(self) -> tuple[str, ...]:
        """The ``-D`` options the kernels are built with: the tile size and the fixed
        kernel tunables (`KERNEL_TUNABLES`). The rules and records reach the kernels through
        clraster.base.layout's generated header instead."""
        g = globals()
        return (f"-DTILE_LOG2={self.tile_log2}",
                *(f"-D{name}={g[name]}" for name in KERNEL_TUNABLES))


def guard_band_factors(width: int, height: int) -> tuple[np.float32, np.float32]:
    """Clip-space guard-band factors (kx, ky): x/y clipping planes are ±k·w.

    Chosen so that window coordinates stay within ±GUARD_BAND_PIXELS of the origin:
    x_win = (x/w + 1) · W/2, so |x/w| ≤ 2·G/W − 1 keeps |x_win| ≤ G.
    """
    kx = np.float32(2.0 * GUARD_BAND_PIXELS / width - 1.0)
    ky = np.float32(2.0 * GUARD_BAND_PIXELS / height - 1.0)
    return kx, ky
