"""Tile raster host side (kernels/raster.cl): one work-item per tile."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..config import RasterConfig
from ..device import program
from ._buffers import GrowBuffer


@dataclass
class FrameBuffers:
    """Raster outputs, H × W image, T tiles.

    depth: float32 (H, W). ids: int32 (H, W). bary: float32 (H, W, 3).
    tile_stats: int64 (T, 2) fragments tested / passed per tile.
    """

    depth: GrowBuffer
    ids: GrowBuffer
    bary: GrowBuffer
    tile_stats: GrowBuffer


class RasterStage:
    def __init__(self, ctx: cl.Context, config: RasterConfig) -> None:
        self.kernel = cl.Kernel(program(ctx, "raster", config.build_options()), "raster_tiles")
        self.config = config
        self.buffers = FrameBuffers(*(GrowBuffer(ctx) for _ in range(4)))

    def run(self, queue: cl.CommandQueue, clip_bary: cl.Buffer, tile_start: cl.Buffer,
            entries: cl.Buffer, width: int, height: int) -> cl.Event:
        b = self.buffers
        tiles_x, tiles_y = self.config.tiles(width, height)
        n_tiles = tiles_x * tiles_y
        npx = width * height
        return self.kernel(queue, (n_tiles,), (1,), clip_bary, tile_start, entries,
                           np.int32(width),
                           np.int32(height), np.int32(tiles_x), b.depth.ensure(4 * npx),
                           b.ids.ensure(4 * npx), b.bary.ensure(12 * npx),
                           b.tile_stats.ensure(16 * n_tiles))
