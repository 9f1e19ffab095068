"""A rendered frame (`Frame`: its buffers, what was culled, and the outputs made from them on
demand) and its per-stage counts (`FrameStats`). The outputs and their files are
`clraster.outputs`, which this module's methods call."""

from __future__ import annotations

import mmap
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..base.layout import (
    ST_BACKFACE,
    ST_CLIPPED,
    ST_DEGENERATE,
    ST_INVALID,
    ST_NO_SAMPLE,
    ST_RASTER,
    ST_TRIVIAL_REJECT,
)
from .outputs import (
    FramePoints,
    distance,
    linear_depth,
    normals,
    point_normals,
    points,
    write_output,
)

if TYPE_CHECKING:
    from ..culling.fates import ClusterFates


def status_counts(status: np.ndarray) -> np.ndarray:
    """int64 (8,): how many triangles have each setup status code (``status`` uint8 (M,),
    layout.ST_*)."""
    # one pass per code: ~4x faster than np.bincount, which first widens the uint8
    # codes to intp (1 ms per frame on the 871K-triangle dragon)
    if not status.size:   # a frame with nothing in view: 8 passes over nothing cost ~8 µs
        return np.zeros(8, np.int64)
    return np.array([np.count_nonzero(status == k) for k in range(8)], np.int64)


#: The object-culling counts `FrameStats.from_status_counts` takes from the culler's dict.
_CULL_COUNT_NAMES = (
    "instances_total", "instances_frustum_culled", "instances_empty",
    "clusters_total", "clusters_frustum_culled", "clusters_cone_culled",
    "clusters_drawn", "triangles_total", "triangles_frustum_culled",
    "triangles_cone_culled", "clusters_occlusion_culled", "triangles_occlusion_culled",
    "clusters_phase1", "clusters_phase2")


@dataclass
class FrameStats:
    """Counts per pipeline stage for one frame, and stage timings when measured.

    Object culling (instances, clusters, triangles): ``*_total`` = in the scene,
    ``*_frustum_culled`` = rejected by the view-frustum test of their bounding volumes,
    ``*_cone_culled`` = clusters whose normal cone faces away. ``triangles_in`` is what was
    sent to triangle setup; it is partitioned into invalid, trivially_rejected,
    backface_culled, degenerate, no_sample, clipped and the unclipped rest that is binned.
    Clipped triangles make ``clip_pieces`` pieces (0..14 each).

    Attributes:
        instances_total, instances_frustum_culled, instances_empty (no faces)
        clusters_total, clusters_frustum_culled, clusters_cone_culled, clusters_drawn
        triangles_total, triangles_frustum_culled, triangles_cone_culled
        clusters_occlusion_culled, triangles_occlusion_culled: removed by two-phase
            occlusion culling (part of clusters_drawn, which counts what the frustum and
            cone tests let through). Hierarchically (`RasterConfig.occlusion_groups`), a
            cluster whose group was hidden counts here without frustum and cone tests.
        clusters_phase1, clusters_phase2: clusters drawn in each occlusion phase.
        triangles_in: sent to setup.
        invalid: dropped because a vertex (or its clip position) is NaN/Inf.
        trivially_rejected: all three vertices outside one frustum plane (outcode AND ≠ 0) or
            one user clip plane.
        backface_culled: facing away under the cull mode.
        degenerate: zero area (edge-on, or after the 1/256-pixel snap).
        no_sample: covers no pixel centre: its bounding box holds none, or (a box of at
            most 4 × 4 centres, tested exactly in setup) none of them is inside it.
        clipped: went through the clip-space clipper (near/far/guard band).
        clip_pieces: triangles the clipper produced that survived.
        rasterized: pieces sent to binning (unclipped survivors + clip_pieces).
        binned_entries: (piece, tile) pairs in the tile lists.
        fragments_tested: covered pixel centres that reached the depth test. With the
            tile Hi-Z (`RasterConfig.tile_hiz`, on by default) a piece behind everything
            its tile already holds is skipped untested; off, this counts every covered
            pixel centre.
        fragments_passed: depth-test passes (each one a depth/id write).
        timings_ms: stage → milliseconds (device stages from OpenCL profiling events).
    """

    instances_total: int = 0
    instances_frustum_culled: int = 0
    instances_empty: int = 0
    clusters_total: int = 0
    clusters_frustum_culled: int = 0
    clusters_cone_culled: int = 0
    clusters_drawn: int = 0
    triangles_total: int = 0
    triangles_frustum_culled: int = 0
    triangles_cone_culled: int = 0
    clusters_occlusion_culled: int = 0
    triangles_occlusion_culled: int = 0
    clusters_phase1: int = 0
    clusters_phase2: int = 0
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
    def from_counts(cls, counts: dict[str, int], status: np.ndarray, **kw: int) -> FrameStats:
        """Stats from the culling counts (cull.DrawList.counts) and the per-triangle setup
        status codes (uint8 (M,))."""
        return cls.from_status_counts(counts, status_counts(status), **kw)

    @classmethod
    def from_status_counts(cls, counts: dict[str, int], c: np.ndarray, **kw: Any
                           ) -> FrameStats:
        """Stats from the culling counts and the number of triangles per setup status code
        (int64 (8,), `status_counts`, summed over the passes of a frame)."""
        obj: dict[str, Any] = {k: int(counts.get(k, 0)) for k in _CULL_COUNT_NAMES}
        # the 8 counts as Python ints at once (each int(c[k]) of a NumPy scalar cost ~1 µs)
        n = [int(v) for v in np.asarray(c).tolist()]
        s = cls(**obj, triangles_in=sum(n), invalid=n[ST_INVALID],
                trivially_rejected=n[ST_TRIVIAL_REJECT], backface_culled=n[ST_BACKFACE],
                degenerate=n[ST_DEGENERATE], no_sample=n[ST_NO_SAMPLE],
                clipped=n[ST_CLIPPED], **kw)
        s.rasterized = n[ST_RASTER] + s.clip_pieces
        return s

    def counts(self) -> dict[str, int]:
        """All counts as a plain dict (no timings)."""
        d = asdict(self)
        d.pop("timings_ms")
        return d

    def __str__(self) -> str:
        g = self.counts()
        rows = [("", "instances", "clusters", "triangles"),
                ("total", g["instances_total"], g["clusters_total"], g["triangles_total"]),
                ("frustum culled", g["instances_frustum_culled"], g["clusters_frustum_culled"],
                 g["triangles_frustum_culled"]),
                ("cone culled", "", g["clusters_cone_culled"], g["triangles_cone_culled"]),
                ("occlusion culled", "", g["clusters_occlusion_culled"],
                 g["triangles_occlusion_culled"]),
                ("sent to setup", "", g["clusters_drawn"] - g["clusters_occlusion_culled"],
                 g["triangles_in"])]
        for k in ("invalid", "trivially_rejected", "backface_culled", "degenerate",
                  "no_sample", "clipped", "clip_pieces", "rasterized", "binned_entries",
                  "fragments_tested", "fragments_passed"):
            rows.append((k.replace("_", " "), "", "", g[k]))
        rows += [(f"time {k} (ms)", "", "", f"{v:.2f}") for k, v in self.timings_ms.items()]

        def fmt(v):
            return f"{v:,}" if isinstance(v, int) else str(v)

        w = max(22, max(len(r[0]) for r in rows) + 1)   # (long stage names: still aligned)
        return "\n".join(f"{a:<{w}}{fmt(b):>12}{fmt(c):>12}{fmt(d):>14}" for a, b, c, d in rows)


@dataclass
class Frame:
    """One rendered frame.

    Attributes:
        depth: (H, W) float32 window depth (z/w + 1)/2 in [0, 1]; 1.0 where nothing was drawn.
            With ``reversed_z`` (``render(..., reversed_z=True)``): (1 − z/w)/2, 1 at the near
            plane, 0 at the far plane and where nothing was drawn.
            Row 0 is the top row; pixel (x, y) is sampled at (x + 0.5, y + 0.5).
        triangle_id: (H, W) int32 face index of the visible triangle, −1 for background.
        barycentrics: (H, W, 3) float32 perspective-correct barycentrics of the pixel centre
            relative to the visible face's three vertices (in the face's own vertex order,
            also for clipped triangles); zeros for background. None when the frame was
            rendered without them (``render(..., outputs=("depth", "ids"))``). Depth and
            barycentrics are interpolated from the unsnapped vertex positions (coverage
            uses the 1/256-px snapped ones), so at a covered pixel centre just outside the
            unsnapped triangle (at most sqrt(2)/512 px) a weight can be slightly negative.
        stats: counts per stage (`FrameStats`).
        overdraw: (H, W) int32 fragments tested per pixel, when asked for
            (``render(..., overdraw=True)``); else None. It sums to fragments_tested: the
            depth-test work done; with ``RasterConfig(tile_hiz=False)`` it is the scene's
            depth complexity (every covered fragment).
        fates: the fate of every cluster of the scene (`clraster.fates.ClusterFates`),
            when asked for (``render(..., fates=True)``); else None.
        reversed_z: whether ``depth`` is reversed-Z (see depth).
        resolved: the per-pixel outputs made on the device by the renderer's resolve stage
            when asked for (``render(..., outputs=("linear_depth", "normals", ...))``,
            names out of `clraster.base.checks.RESOLVE_OUTPUTS`): name → array. "mask"
            bool (H, W); "linear_depth", "distance" float32 (H, W), inf on the background;
            "points" float64 (H, W, 3) world positions, 0 on the background; "normals",
            "smooth_normals", "camera_normals", "smooth_camera_normals" float32 (H, W, 3)
            unit normals, 0 on the background. The methods below (`linear_depth`,
            `distance`, `normals`, `points`, `point_normals`, `mask`, `save`) return these
            arrays when the frame has them (and, for those that take a camera, the camera
            is the one it was rendered with), and compute on the host otherwise.
            `clraster.pipeline.resolving` says how each is made: from the exact surface
            point in float64, so the device's metric depth equals
            ``linear_depth(camera, target)``'s host value to float32 rounding.
        resolved_camera: (view, projection) float64 (4, 4) each: the camera the resolved
            outputs were made with, when one of them needs it; else None.
        source: a weak reference to the OpenCL renderer that made the frame (None from the
            NumPy twin): `clraster.shade.shade` shades on its device.
    """

    depth: np.ndarray
    triangle_id: np.ndarray
    barycentrics: np.ndarray | None
    stats: FrameStats
    overdraw: np.ndarray | None = None
    fates: ClusterFates | None = None
    reversed_z: bool = False
    resolved: dict[str, np.ndarray] = field(default_factory=dict)
    resolved_camera: tuple[np.ndarray, np.ndarray] | None = None
    source: Any = field(default=None, repr=False, compare=False)

    @classmethod
    def empty(cls, width: int, height: int, stats: FrameStats | None = None,
              bary: bool = True, reversed_z: bool = False) -> Frame:
        """A frame with nothing drawn: depth 1.0 (0.0 with reversed_z), ids −1,
        barycentrics 0 (None without ``bary``). The zeros are fresh pages from the OS
        (`mmap`), which cost nothing until touched (``np.zeros`` may clear reused heap
        memory instead: 4 ms at 1080p)."""
        n = width * height
        zeros = np.frombuffer(mmap.mmap(-1, max(12 * n, 1)), np.float32, count=3 * n)
        depth = np.full((height, width), 0.0 if reversed_z else 1.0, np.float32)
        return cls(depth, np.full((height, width), -1, np.int32),
                   zeros.reshape(height, width, 3) if bary else None, stats or FrameStats(),
                   reversed_z=bool(reversed_z))

    def need_barycentrics(self) -> np.ndarray:
        """``barycentrics``, or a ValueError saying how to get them when the frame was
        rendered without them."""
        if self.barycentrics is None:
            raise ValueError("this frame was rendered without barycentrics; render it with "
                             "outputs including 'bary' (the default)")
        return self.barycentrics

    @property
    def width(self) -> int:
        return int(self.depth.shape[1])

    @property
    def height(self) -> int:
        return int(self.depth.shape[0])

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: pixels covered by some triangle (the device-made "mask" when the
        frame has it)."""
        got = self.resolved.get("mask")
        return got if got is not None else self.triangle_id >= 0

    def visible_faces(self) -> np.ndarray:
        """Sorted int32 array of the face indices visible in at least one pixel."""
        ids = np.unique(self.triangle_id)
        return ids[ids >= 0].astype(np.int32)

    # Outputs that need the camera or the geometry take them as arguments (the frame holds
    # only its buffers); the work is in clraster.outputs (meshes, scenes, shading, files).

    def linear_depth(self, camera: Any, target: Any = None) -> np.ndarray:
        """(H, W) float32 depth along the view axis in scene units (−z in eye space for a
        rigid view); inf on the background.

        Args:
            camera: the camera the frame was rendered with (`clraster.Camera`).
            target: optional, the Mesh / Scene / trimesh object it was rendered from: the
                depth then comes from the exact surface points (ids + barycentrics,
                float64) instead of the float32 window depth, whose metric error grows as
                distance² · (far − near) / (far · near) (~1e-6 relative at moderate range).

        A frame rendered with ``outputs=(..., "linear_depth")`` returns its device-made
        array (exact surface points, as with a target) when ``camera`` is the one it was
        rendered with (`resolved`), whether or not ``target`` is given.
        """
        return linear_depth(self, camera, target)

    def distance(self, camera: Any, target: Any = None) -> np.ndarray:
        """(H, W) float32 distance from the eye to the surface along each pixel's ray
        (the ray through the pixel centre), scene units; inf on the background. For an
        orthographic camera, the depth from the image plane. `target` as in
        :meth:`linear_depth`."""
        return distance(self, camera, target)

    def normals(self, target: Any, smooth: bool = False, space: str = "world",
                camera: Any = None) -> np.ndarray:
        """(H, W, 3) float32 unit normals of the visible surface, zeros on the background.

        Args:
            target: the Mesh / Scene / trimesh object the frame was rendered from.
            smooth: False: face normals ``normalize((b − a) × (c − a))``; True: area-weighted
                vertex normals interpolated with the barycentrics. Scene instances map
                them with the inverse transpose of their transform, outward also for a
                mirroring one (glTF's rule).
            space: "world", or "camera" (OpenGL eye space: x right, y up, z towards the
                viewer; needs `camera`).
        """
        return normals(self, target, smooth=smooth, space=space, camera=camera)

    def points(self, target: Any, space: str = "world", camera: Any = None) -> FramePoints:
        """The covered pixels as a point cloud: ``(points, ids, pixels)`` — (N, 3) float64
        positions (barycentrics applied to the face's world-space vertices), (N,) int32
        triangle ids, (N, 2) int32 pixel (x, y); row-major pixel order.

        Args:
            target: the Mesh / Scene / trimesh object the frame was rendered from.
            space: "world", or "camera": the world points mapped by ``camera.view`` into
                OpenGL eye space (x right, y up, z towards the viewer; needs `camera`).
        Their normals, in the same order: `point_normals`."""
        return points(self, target, space=space, camera=camera)

    def point_normals(self, target: Any, smooth: bool = False, space: str = "world",
                      camera: Any = None) -> np.ndarray:
        """(N, 3) float32 unit normals of the covered pixels, in the order of `points`:
        :meth:`normals` (same ``smooth``, ``space``, ``camera``) at those pixels."""
        return point_normals(self, target, smooth=smooth, space=space, camera=camera)

    def save(self, path: str | os.PathLike, what: str = "depth", **options: Any) -> Path:
        """Write one output ("depth", "linear_depth", "distance", "ids", "bary", "mask",
        "normals", "shaded", "points") to exactly `path`, in the format its extension names
        (.png, .tif/.tiff, .exr, .npy, .npz, .ply): `clraster.outputs.write_output`, whose
        keyword options (``target``, ``camera``, ``depth_scale``, ``smooth``, ``space``...)
        pass through. "points" are written with their normals (.ply: float32 x y z nx ny
        nz; .npy: (N, 6) float64), in world space or, with ``space="camera"``, in eye
        space. An option the output does not read is refused (ValueError naming it)."""
        return write_output(path, self, what, **options)
