"""The stage chain, written once: geometry → setup (with the vertex transform) → bin
(→ raster).

Each stage's ``run`` takes the upstream stage's buffers object and the frame's
`clraster.pipeline.params.FrameParams`, and returns its own buffers object (each dataclass documents
its fields' sizes and dtypes) with its profiling events. `StageChain` runs them in order over
any set of draws — a whole frame, one phase of occlusion culling
(`clraster.pipeline.twophase`), the boxes of an occlusion query
(`clraster.pipeline.stages.query`), or a bounded batch of a streamed frame — and adds each
pass's counts and device times to the frame's `clraster.pipeline.params.FrameTotals`, so a
frame drawn in several passes into the same frame buffers reports the sums.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any, cast

import pyopencl as cl

from ...base.config import RasterConfig
from ...base.layout import DRAW_DTYPE, PIECE_DTYPE
from ..device import abandon, event_ms, wait
from ..draws import FrameDraws
from ..params import BinBudgetExceeded, FrameParams, FrameTotals
from ._buffers import GrowBuffer
from .bin import BinBuffers, BinStage
from .geometry import GeometryStage
from .raster import RasterOutput, RasterStage
from .setup import SetupStage


class StageChain:
    """One set of stages (and so one set of device buffers) run in pipeline order.

    Args:
        ctx: the OpenCL context. config: tunables (tile size, bin chunks).
        raster: also make the raster stage (`draw`); an occlusion query only bins.

    The buffers are reused from pass to pass and grown geometrically; a pass overwrites the
    previous pass's stage buffers (not the frame buffers it rasterizes into).

    A pass whose host code writes buffers (the draw records, setup's flag: host mode,
    `GrowBuffer`) relies on the queue being idle when it starts, which `draw` leaves it.
    `bin` returns with its last stages still running, and a pass ended by an exception
    (Ctrl-C in a wait, an error between launches) may leave work running that reads and
    writes them: the next pass then first waits for it (`_pass`), and after an exception
    the chain keeps itself alive until that work is done (`clraster.device.abandon`).
    """

    def __init__(self, ctx: cl.Context, config: RasterConfig, *, raster: bool = True) -> None:
        self.context = ctx
        self.config = config
        self.geometry = GeometryStage(ctx)
        self.setup = SetupStage(ctx, config)
        self.binning = BinStage(ctx, config)
        self.raster = RasterStage(ctx, config) if raster else None
        for gb, nbytes in self.budget_bounds().items():
            gb.bound = nbytes
        #: the queue may still run work of the last pass (a `bin`, or a pass ended by an
        #: exception) that the host has not waited for
        self._pending = False

    @contextlib.contextmanager
    def _pass(self, queue: cl.CommandQueue, leaves_work: bool) -> Iterator[None]:
        """Around one pass (`bin`: ``leaves_work``, `draw`): first wait for what the last
        pass may have left running; on an exception other than BinBudgetExceeded (raised
        only once the queue is idle), abandon what is enqueued, keeping the chain and its
        buffers alive until it is done."""
        if self._pending:
            wait(queue, keep=self)
            self._pending = False
        try:
            yield
        except BinBudgetExceeded:
            raise
        except BaseException:
            self._pending = True
            abandon(queue, self)
            raise
        self._pending = leaves_work

    def budget_bounds(self) -> dict:
        """Bytes each per-pass buffer may need under the config's budget (GrowBuffer →
        bytes), M = batch_triangles, E = batch_entries: draw records 32·M (a draw has at
        least one triangle), setup 117·M (96-byte record, status, clip count and offset,
        single tile, the clipped triangles' list), clipped pieces 132·E (record +
        barycentrics; a pass with more pieces than E is split like one with too many
        entries), bin entries 96·E and the list of slots to bin 4·M. The per-tile buffers
        (C·T counts, tile starts, tile stats) depend on the image only."""
        m, e = self.config.batch_triangles, self.config.batch_entries
        g, s, b = self.geometry.buffers, self.setup.buffers, self.binning.buffers
        return {g.draws: DRAW_DTYPE.itemsize * m, s.pieces: PIECE_DTYPE.itemsize * m,
                s.status: m, s.clip_count: 4 * m, s.clip_offset: 4 * m, s.tile1: 4 * m,
                s.clip_list: 8 * m,
                s.clip_pieces: PIECE_DTYPE.itemsize * e, s.clip_bary: 36 * e,
                b.entries: PIECE_DTYPE.itemsize * e, b.live: 4 * m}

    def trim(self) -> None:
        """Release the per-pass buffers left above the budget's bound (`budget_bounds`) by
        an outsized pass (a single draw over the entry budget); call between frames."""
        for gb in self.budget_bounds():
            gb.trim()

    def device_bytes(self) -> int:
        """Bytes of device memory the chain's buffers hold now (pool included)."""
        stages: list[Any] = [self.geometry, self.setup, self.binning]
        if self.raster is not None:
            stages.append(self.raster)
        su = self.setup
        total = (su.partial.capacity + su.n_clipped.capacity + su.scratch.capacity
                 + su.scratch_bary.capacity)
        for st in stages:
            total += sum(gb.capacity for gb in vars(st.buffers).values()
                         if isinstance(gb, GrowBuffer))
        return total

    def bin(self, queue: cl.CommandQueue, pool, fd: FrameDraws, params: FrameParams,
            totals: FrameTotals, *, max_entries: int | None = None) -> BinBuffers:
        """Run geometry upload → setup → bin over the draws ``fd`` of ``pool`` (a
        `drawlist.GeometryPool` or `clraster.pipeline.boxes.BoxGeometry`; uploaded only when it is a
        different object from last time). Adds the clipped pieces, binned entries and the
        stages' events (pending, see `FrameTotals.settle`) to ``totals``.

        Returns the bin buffers (tile lists); the setup buffers stay in ``self.setup``.
        The last stages may still be running: read the outputs through the same queue.

        ``max_entries``: the pass's bin-entry budget (None: none). Over it — more entries,
        or more clipped pieces — `clraster.pipeline.params.BinBudgetExceeded` is raised before
        anything is counted in ``totals`` (only the device times of the work done).
        """
        with self._pass(queue, leaves_work=True):
            return self._bin_pass(queue, pool, fd, params, totals, max_entries)

    def _bin_pass(self, queue: cl.CommandQueue, pool, fd: FrameDraws, params: FrameParams,
                  totals: FrameTotals, max_entries: int | None) -> BinBuffers:
        try:
            bins, events, n_clip = self._bin(queue, pool, fd, params, max_entries, False)
        except BinBudgetExceeded as e:   # the device time spent still counts
            _add_events(totals, e.stage_events)
            raise
        totals.clip_pieces += n_clip
        totals.binned_entries += bins.n_entries
        _add_events(totals, events)
        return bins

    def _bin(self, queue: cl.CommandQueue, pool, fd: FrameDraws, params: FrameParams,
             max_entries: int | None, defer: bool) -> tuple[BinBuffers, dict, int]:
        """`bin` without touching a FrameTotals: the bin buffers (pending with ``defer``:
        `BinStage.run`), the events by stage and the clipped pieces. On
        BinBudgetExceeded, its ``stage_events`` are the events by stage of the work done."""
        self.geometry.upload_pool(queue, pool)
        geo = self.geometry.upload_frame(queue, fd)
        self.setup.prepare(queue)   # while the queue is idle (SetupStage.prepare)
        events: dict[str, list] = {}
        stage = "setup"
        try:
            setup, events["setup"] = self.setup.run(queue, geo, params, max_pieces=max_entries)
            stage = "bin"
            bins, events["bin"] = self.binning.run(queue, setup, params, max_entries,
                                                   defer=defer)
        except BinBudgetExceeded as e:
            events[stage] = e.events
            e.stage_events = events
            raise
        return bins, events, setup.n_clip_pieces

    def draw(self, queue: cl.CommandQueue, pool, fd: FrameDraws, params: FrameParams,
             totals: FrameTotals, *, into: RasterOutput | None = None,
             overdraw: bool = False, max_entries: int | None = None, bary: bool = True,
             follow: Follow | None = None
             ) -> RasterOutput:
        """`bin`, then rasterize into ``into`` (the frame buffers of an earlier pass of the
        same frame, whose depth and ids take part in the depth test) or, when None, into
        fresh cleared frame buffers. Adds the setup status of every triangle, the fragment
        counts and the device times (settled) to ``totals``.

        Returns the frame buffers, complete and readable. With no triangles in ``fd``
        nothing runs: ``into`` is returned as it is, or fresh cleared buffers.
        ``max_entries``: as in `bin` (over it, nothing is drawn or counted). ``bary``:
        fresh buffers get barycentrics (False: none computed, ``out.bary`` is None).
        ``follow(queue, out, bins, redraw)``: called right after each raster launch, before
        the wait, to enqueue what reads the frame (`clraster.pipeline.stages.resolve.
        ResolveFollow`; ``bins``: the launch's bin buffers, whose list the raster skips
        when it did not fit; ``redraw``: the pass drawn again); the wait keeps it alive,
        and should it raise, the frame buffers and it are kept until the queue is done.

        This is one pass of whatever size ``fd`` is; `clraster.pipeline.streaming.stream_draws`
        cuts a frame into passes within the config's budget.
        """
        with self._pass(queue, leaves_work=False):
            return self._draw_pass(queue, pool, fd, params, totals, into, overdraw,
                                   max_entries, bary, follow)

    def _draw_pass(self, queue: cl.CommandQueue, pool, fd: FrameDraws, params: FrameParams,
                   totals: FrameTotals, into: RasterOutput | None, overdraw: bool,
                   max_entries: int | None, bary: bool,
                   follow: Follow | None
                   ) -> RasterOutput:
        if fd.n_tris == 0:
            if into is None:   # nothing to draw yet: a cleared frame to continue from
                into = cast(RasterStage, self.raster).clear(queue, params, overdraw, bary)
            return into
        raster = cast(RasterStage, self.raster)   # a chain built with raster=True draws
        raster.prepare(queue, params)   # while the queue is idle
        try:
            bins, events, n_clip = self._bin(queue, pool, fd, params, max_entries, True)
        except BinBudgetExceeded as e:   # the device time spent still counts
            _add_events(totals, e.stage_events)
            raise
        setup = self.setup.buffers
        out, load = raster.outputs(params, into, overdraw, bary)
        events["raster"] = [raster.launch(queue, setup, bins, params, out, load)]
        _follow(queue, follow, out, bins, False)
        raster.wait(queue, out, follow)
        self.setup.check_unclipped(queue, self.geometry.buffers)
        if bins.pending:
            # the scatter and raster ran without waiting for the list's length (BinStage.run
            # with defer); a list that did not fit drew nothing: scattered again, drawn again
            try:
                again = self.binning.settle(queue, params, max_entries, events["bin"])
            except BinBudgetExceeded:   # nothing was drawn
                _add_events(totals, events)
                raise
            if again:
                events["raster"].append(raster.launch(queue, setup, bins, params, out, load))
                _follow(queue, follow, out, bins, True)
                raster.wait(queue, out, follow)
        rstats = raster.finish(queue, params, out)
        totals.clip_pieces += n_clip
        totals.binned_entries += bins.n_entries
        totals.status_counts += bins.status_counts   # counted on the device (bin_count)
        totals.fragments_tested += int(rstats[:, 0].sum())
        totals.fragments_passed += int(rstats[:, 1].sum())
        _add_events(totals, events)
        totals.settle(event_ms)   # the raster waited for the queue: every event is complete
        return out


#: `StageChain.draw`'s ``follow``: (queue, frame buffers, bin buffers, redraw) → None.
Follow = Callable[[cl.CommandQueue, RasterOutput, BinBuffers, bool], None]


def _follow(queue: cl.CommandQueue, follow: Follow | None, out: RasterOutput,
            bins: BinBuffers, redraw: bool) -> None:
    """``follow`` after a raster launch; on an exception (an interrupt, a failed
    allocation) the raster still runs: ``out`` and ``follow`` are kept until it is done."""
    if follow is None:
        return
    try:
        follow(queue, out, bins, redraw)
    except BaseException:
        abandon(queue, (out, follow))
        raise


def _add_events(totals: FrameTotals, events: dict[str, list]) -> None:
    """Add the events by stage (`StageChain._bin`) to ``totals`` (pending, see
    `FrameTotals.settle`)."""
    for stage, ev in events.items():
        totals.add_events(stage, ev)
