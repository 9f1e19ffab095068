"""Binning host side (kernels/bin.cl): count → offsets → scan → scatter."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pyopencl as cl

from ...base.config import MIN_CHUNK_TRIANGLES, RasterConfig
from ...base.layout import PIECE_DTYPE
from ..device import kernel, program, wait
from ..params import BinBudgetExceeded, FrameParams
from ._buffers import GrowBuffer
from .setup import SetupBuffers


@dataclass
class BinBuffers:
    """Binning → raster boundary, T = number of tiles, C = bin chunks, E = entries.

    counts: int32 (C, T) per-chunk tile counts, then per-chunk offsets within each tile.
    tile_count: int32 (T,). tile_start: int32 (T + 1,), tile_start[T] = E.
    hist: int32 (C, 8) triangles per setup status code (config.ST_*) per chunk.
    live: int32 (M,) per chunk, from the chunk's first slot on, the slots that have
    something to bin (setup's tile1 not TILE1_NONE), in order; n_live: int32 (C,) how many.
    summary: int32 (10,): E (clamped), 1 when E would not fit an int32, then the status
    counts summed over the chunks.
    entries: PIECE_DTYPE (E,) copies of the setup records, tile-major, submission order
    within a tile.
    n_entries: E of the last run.
    cap: entry records the scatter was given room for (>= E once the run is complete).
    pending: the last run was deferred (`BinStage.run`): E, status_counts and whether
    the list fit are not known on the host until `BinStage.settle`.
    """

    counts: GrowBuffer
    tile_count: GrowBuffer
    tile_start: GrowBuffer
    summary: GrowBuffer
    entries: GrowBuffer
    hist: GrowBuffer
    live: GrowBuffer
    n_live: GrowBuffer
    n_entries: int = 0
    status_counts: np.ndarray = field(default_factory=lambda: np.zeros(8, np.int64))
    cap: int = 0
    pending: bool = False


class BinStage:
    def __init__(self, ctx: cl.Context, config: RasterConfig) -> None:
        prg = program(ctx, "bin", config.build_options())
        self.k_count, self.k_offsets, self.k_scan, self.k_scatter = (
            kernel(prg, name)
            for name in ("bin_count", "bin_offsets", "bin_scan_tiles", "bin_scatter"))
        self.config = config
        self.buffers = BinBuffers(*(GrowBuffer(ctx) for _ in range(8)))  # type: ignore[arg-type]  # one GrowBuffer per buffer field
        self.buffers.summary = GrowBuffer(ctx, host=True)   # read after a wait

    def run(self, queue: cl.CommandQueue, setup: SetupBuffers, params: FrameParams,
            max_entries: int | None = None, *, defer: bool = False
            ) -> tuple[BinBuffers, list[cl.Event]]:
        """Bin the pieces of setup's ``n_tris`` triangles into per-tile lists. Returns the
        buffers (n_entries = E, status_counts = triangles per setup status code) and the
        profiling events.

        ``max_entries``: when the count → scan step finds E > max_entries, raise
        `clraster.pipeline.params.BinBudgetExceeded` (E) before the entry buffer is sized or
        written (the streamed frame draws these triangles again in smaller batches);
        None: no limit (a single draw).

        ``defer``: do not wait for E to size the entry buffer: scatter at once into the
        buffer as it is (room for ``cap`` entries, at most max_entries); a list that does
        not fit is not written (bin.cl BIN_LIST_OVER), nor drawn by the raster kernel
        given the same summary and cap. The result is ``pending`` until `settle`, after
        the raster's wait, reads E and, when it did not fit, scatters again into a larger
        buffer (the caller then draws again). This saves a host round trip per pass: the
        wait for E, the read, and the launch of scatter and raster behind it, during
        which the device idled (~0.15 ms after the scan and ~0.2 ms before the raster of
        spot at 1080p on two cores, from the profiling events' timeline). A renderer's
        entry buffer keeps its size from frame to frame, so after the first frames a
        pass almost never needs the second scatter."""
        b = self.buffers
        m = setup.n_tris
        tiles_x, n_tiles = params.tiles_x, params.n_tiles
        # Chunks of at least MIN_CHUNK_TRIANGLES: the per-chunk rows (chunks × tiles counts,
        # cleared, then scanned per tile) are a fixed cost per chunk, which a small mesh
        # cut into 64 chunks would pay in full (bin_offsets ~10× on spot at 1080p); a few
        # chunks per core still balance the count and scatter.
        chunks = max(1, min(self.config.bin_chunks, -(-m // MIN_CHUNK_TRIANGLES)))
        counts = b.counts.ensure(4 * chunks * n_tiles)
        common = (setup.status.buf, setup.clip_count.buf, setup.clip_offset.buf,
                  setup.pieces.buf, setup.clip_pieces.buf, np.uint32(m),
                  np.uint32(chunks), np.int32(tiles_x), np.int32(n_tiles), counts,
                  setup.tile1.buf)
        hist = b.hist.ensure(4 * 8 * chunks)
        live = (b.live.ensure(4 * max(m, 1)), b.n_live.ensure(4 * chunks))
        ev = [self.k_count(queue, (chunks,), (1,), *common, hist, *live)]
        ev.append(self.k_offsets(queue, (n_tiles,), None, np.uint32(chunks),
                                 np.int32(n_tiles), counts, b.tile_count.ensure(4 * n_tiles)))
        tile_start = b.tile_start.ensure(4 * (n_tiles + 1))
        summary_buf = b.summary.ensure(40)
        ev.append(self.k_scan(queue, (1,), (1,), np.int32(n_tiles), b.tile_count.buf,
                              tile_start, np.uint32(chunks), hist, summary_buf))
        self._scatter_args = (chunks, common, tile_start, summary_buf, live)
        rec = PIECE_DTYPE.itemsize
        if defer and b.entries.capacity >= rec:
            cap = b.entries.capacity // rec
            if max_entries is not None:
                cap = min(cap, max_entries)
            ev.append(self._scatter(queue, cap))
            b.pending, b.cap = True, cap
            return b, ev
        wait(queue)   # interruptibly, with the GIL free (device.wait)
        summary = b.summary.read(queue, np.int32, 10)
        e = self._check(summary, params, max_entries, ev)
        b.entries.ensure(rec * e, "bin list")
        ev.append(self._scatter(queue, e))
        b.pending, b.cap = False, e
        return b, ev

    def settle(self, queue: cl.CommandQueue, params: FrameParams, max_entries: int | None,
               events: list) -> bool:
        """Complete a deferred `run` once the device has run the scatter (and the raster
        behind it): read E and the status counts; raise as `run` does (max_entries,
        more entries than an int holds). Returns True when the list did not fit: then it
        has been scattered again into a buffer of E entries (its event appended to
        ``events``) and the pass must be drawn again; False when it was complete."""
        b = self.buffers
        summary = b.summary.read(queue, np.int32, 10)   # the raster's wait saw the scan
        e = self._check(summary, params, max_entries, events)
        b.pending = False
        if e <= b.cap:
            return False
        b.entries.ensure(PIECE_DTYPE.itemsize * e, "bin list")
        events.append(self._scatter(queue, e))
        b.cap = e
        return True

    def _scatter(self, queue: cl.CommandQueue, cap: int) -> cl.Event:
        """bin_scatter into the entry buffer, which holds ``cap`` records."""
        chunks, common, tile_start, summary_buf, live = self._scatter_args
        return self.k_scatter(queue, (chunks,), (1,), *common, tile_start,
                              self.buffers.entries.buf, summary_buf, np.int32(cap), *live)

    def _check(self, summary: np.ndarray, params: FrameParams, max_entries: int | None,
               events: list) -> int:
        """E from the scan's ``summary``, with the status counts kept; raises
        BinBudgetExceeded (over max_entries) or ValueError (over 2**31 entries)."""
        b = self.buffers
        head, over = int(summary[0]), int(summary[1])
        if max_entries is not None and (over or head > max_entries):
            raise BinBudgetExceeded(2**31 if over else head, max_entries, events)
        b.status_counts = summary[2:].astype(np.int64)
        if over:
            raise ValueError(
                f"binning would need more than 2**31 (piece, tile) entries at "
                f"{params.width}x{params.height} with {self.config.tile_size}px tiles; use a "
                "larger tile size (RasterConfig(tile_log2=...)) or a smaller image")
        b.n_entries = head
        return head
