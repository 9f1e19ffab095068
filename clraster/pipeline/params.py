"""What every stage of one frame reads (`FrameParams`) and what the passes of a frame add up
(`FrameTotals`); plain data shared by the OpenCL stage chain and the NumPy twin.

A frame may run the stage chain (geometry → setup → bin → raster) several times
into the same frame buffers — the two phases of occlusion culling, and within each the
bounded batches of a streamed frame (`clraster.pipeline.streaming`) — so the per-frame parameters
are built once and passed to every pass, and the counts and timings of the passes
accumulate in one `FrameTotals`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..base.config import RasterConfig, guard_band_factors
from ..base.layout import CULL_MODES
from ..output.frame import FrameStats, status_counts


class BinBudgetExceeded(Exception):
    """Raised by a pass whose bin list would hold more than its ``max_entries`` (binning's
    count → scan step found ``entries``), before anything is drawn or added to the frame's
    counts. ``events``: device events of the work already done (their times still count)."""

    def __init__(self, entries: int, max_entries: int, events: list | None = None) -> None:
        super().__init__(f"this pass needs {entries:,} bin entries, over its budget of "
                         f"{max_entries:,}")
        self.entries = int(entries)
        self.events = list(events or [])
        #: the events of the pass's work by stage (filled in by clraster.pipeline.stages.chain)
        self.stage_events: dict[str, list] = {}


@dataclass(frozen=True)
class FrameParams:
    """Per-frame parameters of every stage, built once per frame (`make`).

    width, height: image size in pixels. cull: "none", "back" or "front" (cull mode of
    triangle setup). kx, ky: float32 clip-space guard-band factors
    (`config.guard_band_factors`: the x/y clipping planes are ±k·w). tiles_x, tiles_y:
    tiles covering the image at the config's tile size. reversed_z: the frame's depth
    convention (`Renderer.render`): the kernels' z-buffer holds a key where less is nearer,
    window depth (z/w + 1)/2 by default, or minus the reversed-Z depth (1 − z/w)/2, whose
    float32 values keep their relative precision far away; `finish_depth` turns the key
    buffer into the depth the frame returns. window: uint8 (H, W) C-contiguous mask of
    the pixels a polygon window lets through (`clraster.window.window_mask`), or None.
    """

    width: int
    height: int
    cull: str
    kx: np.float32
    ky: np.float32
    tiles_x: int
    tiles_y: int
    reversed_z: bool = False
    window: np.ndarray | None = None

    @classmethod
    def make(cls, width: int, height: int, config: RasterConfig, cull: str = "back",
             reversed_z: bool = False, window: np.ndarray | None = None) -> FrameParams:
        kx, ky = guard_band_factors(width, height)
        tiles_x, tiles_y = config.tiles(width, height)
        mask = None if window is None else np.ascontiguousarray(window, np.uint8)
        return cls(int(width), int(height), cull, kx, ky, tiles_x, tiles_y, bool(reversed_z),
                   mask)

    @property
    def zoff(self) -> float:
        """The depth key as a function of z/w, key = (z/w)/2 + zoff: the Hi-Z box test's
        (kernels/pyramid.cl) bound for either convention (setup computes the key itself
        from its depth rows, kernels/setup.cl DEPTH_MODE)."""
        return -0.5 if self.reversed_z else 0.5

    @property
    def n_tiles(self) -> int:
        return self.tiles_x * self.tiles_y

    @property
    def cull_mode(self) -> int:
        """The cull mode as the kernels read it (config.CULL_MODES)."""
        return CULL_MODES[self.cull]


@dataclass
class FrameTotals:
    """Counts and timings summed over the passes of one frame.

    status_counts: int64 (8,) triangles per setup status code (config.ST_*), summed over
    the passes: counts, not per-triangle arrays, so a frame's host memory does not grow with
    the triangles it draws.
    clip_pieces, binned_entries, fragments_tested, fragments_passed: sums over the passes.
    timings_ms: stage → milliseconds, in first-seen order (the caller may put host stages,
    e.g. "cull (host)", in first). pending: stage → OpenCL profiling events not yet added to
    timings_ms (`settle` adds them once they are complete).
    """

    status_counts: np.ndarray = field(default_factory=lambda: np.zeros(8, np.int64))
    clip_pieces: int = 0
    binned_entries: int = 0
    fragments_tested: int = 0
    fragments_passed: int = 0
    timings_ms: dict[str, float] = field(default_factory=dict)
    pending: dict[str, list] = field(default_factory=dict)

    def add_status(self, status: np.ndarray) -> None:
        """Count one pass's per-triangle setup status codes (uint8 (M_pass,))."""
        self.status_counts += status_counts(status)

    def add_time(self, stage: str, ms: float) -> None:
        self.timings_ms[stage] = self.timings_ms.get(stage, 0.0) + ms

    def add_events(self, stage: str, events: list) -> None:
        """Keep ``events`` (OpenCL profiling events; None entries are skipped) of ``stage``
        until `settle`; their times are known only once they are complete."""
        self.pending.setdefault(stage, []).extend(e for e in events if e is not None)

    def settle(self, event_ms: Callable[[list], float]) -> None:
        """Add the device times of the pending events to timings_ms, each stage's from
        ``event_ms(events)`` (milliseconds: `clraster.pipeline.device.event_ms`); call once
        they are complete (after a blocking read or a wait on their queue)."""
        for stage, events in self.pending.items():
            self.add_time(stage, event_ms(events))
        self.pending.clear()

    def stats(self, counts: dict[str, int]) -> FrameStats:
        """The frame's `FrameStats` from the culling counts (cull.DrawList.counts plus the
        occlusion rows) and these totals; timings included."""
        s = FrameStats.from_status_counts(counts, self.status_counts,
                                          clip_pieces=self.clip_pieces,
                                          binned_entries=self.binned_entries,
                                          fragments_tested=self.fragments_tested,
                                          fragments_passed=self.fragments_passed)
        s.timings_ms = dict(self.timings_ms)
        return s


def finish_depth(key: np.ndarray, ids: np.ndarray, reversed_z: bool) -> np.ndarray:
    """The frame's depth from the raster's key buffer (float32 (H, W), in place): unchanged
    for ordinary depth; for reversed-Z, −key where a triangle was drawn (near → 1, far → 0)
    and 0.0 (the far plane) where nothing was (the key buffer's clear value is 1.0)."""
    if reversed_z:
        np.negative(key, out=key)
        key[ids < 0] = 0.0
    return key
