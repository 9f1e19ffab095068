"""Frame outputs and per-frame statistics (plain data; imports nothing above config)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .config import (
    ST_BACKFACE,
    ST_CLIPPED,
    ST_DEGENERATE,
    ST_INVALID,
    ST_NO_SAMPLE,
    ST_RASTER,
    ST_TRIVIAL_REJECT,
)


@dataclass
class FrameStats:
    """Counts per pipeline stage for one frame, and stage timings when measured.

    Triangle counts partition ``triangles_in``: every input triangle ends in exactly one of
    invalid, trivially_rejected, backface_culled, degenerate, no_sample, clipped or
    unclipped (= sent to binning unclipped). Clipped triangles make ``clip_pieces`` pieces
    (0..14 each; a piece whose snapped area is zero or that faces away is dropped).

    Attributes:
        triangles_in: faces submitted.
        invalid: dropped because a vertex (or its clip position) is NaN/Inf.
        trivially_rejected: all three vertices outside one frustum plane (outcode AND ≠ 0).
        backface_culled: facing away under the cull mode (unclipped triangles).
        degenerate: zero area after the 1/256-pixel snap.
        no_sample: bounding box contains no pixel centre, so it covers nothing.
        clipped: went through the clip-space clipper (near/far/guard band).
        clip_pieces: triangles the clipper produced that survived.
        rasterized: pieces sent to binning (unclipped survivors + clip_pieces).
        binned_entries: (piece, tile) pairs in the tile lists.
        fragments_tested: covered pixel centres that reached the depth test.
        fragments_passed: depth-test passes (each one a depth/id write).
        timings_ms: stage name → milliseconds (OpenCL profiling events; empty for the twin).
    """

    triangles_in: int = 0
    invalid: int = 0
    trivially_rejected: int = 0
    backface_culled: int = 0
    degenerate: int = 0
    no_sample: int = 0
    clipped: int = 0
    clip_pieces: int = 0
    rasterized: int = 0
    binned_entries: int = 0
    fragments_tested: int = 0
    fragments_passed: int = 0
    timings_ms: dict[str, float] = field(default_factory=dict)

    @classmethod
    def from_status(cls, status: np.ndarray, **kw: int) -> FrameStats:
        """Triangle counts from the per-triangle setup status codes (uint8 (M,))."""
        c = np.bincount(status, minlength=8)
        s = cls(triangles_in=int(status.size), invalid=int(c[ST_INVALID]),
                trivially_rejected=int(c[ST_TRIVIAL_REJECT]),
                backface_culled=int(c[ST_BACKFACE]), degenerate=int(c[ST_DEGENERATE]),
                no_sample=int(c[ST_NO_SAMPLE]), clipped=int(c[ST_CLIPPED]), **kw)
        if "rasterized" not in kw:
            s.rasterized = int(c[ST_RASTER]) + s.clip_pieces
        return s

    def counts(self) -> dict[str, int]:
        """All counts as a plain dict (no timings)."""
        d = asdict(self)
        d.pop("timings_ms")
        return d

    def __str__(self) -> str:
        rows = [(k.replace("_", " "), f"{v:,}") for k, v in self.counts().items()]
        rows += [(f"time {k} (ms)", f"{v:.3f}") for k, v in self.timings_ms.items()]
        w = max(len(r[0]) for r in rows)
        return "\n".join(f"{a:<{w}}  {b:>14}" for a, b in rows)


@dataclass
class Frame:
    """One rendered frame.

    Attributes:
        depth: (H, W) float32 window depth (z/w + 1)/2 in [0, 1]; 1.0 where nothing was drawn.
            Row 0 is the top row; pixel (x, y) is sampled at (x + 0.5, y + 0.5).
        triangle_id: (H, W) int32 face index of the visible triangle, −1 for background.
        barycentrics: (H, W, 3) float32 perspective-correct barycentrics of the pixel centre
            relative to the visible face's three vertices (in the face's own vertex order,
            also for clipped triangles); zeros for background.
        stats: counts per stage (`FrameStats`).
    """

    depth: np.ndarray
    triangle_id: np.ndarray
    barycentrics: np.ndarray
    stats: FrameStats

    @classmethod
    def empty(cls, width: int, height: int, stats: FrameStats | None = None) -> Frame:
        """A frame with nothing drawn: depth 1.0, ids −1, barycentrics 0."""
        return cls(np.ones((height, width), np.float32), np.full((height, width), -1, np.int32),
                   np.zeros((height, width, 3), np.float32), stats or FrameStats())

    @property
    def width(self) -> int:
        return int(self.depth.shape[1])

    @property
    def height(self) -> int:
        return int(self.depth.shape[0])

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: pixels covered by some triangle."""
        return self.triangle_id >= 0

    def visible_faces(self) -> np.ndarray:
        """Sorted int32 array of the face indices visible in at least one pixel."""
        ids = np.unique(self.triangle_id)
        return ids[ids >= 0].astype(np.int32)
