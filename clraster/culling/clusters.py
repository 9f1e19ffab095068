"""Clusters (meshlets): a mesh cut into small, spatially coherent groups of triangles.

A :class:`ClusteredMesh` is the unit of object culling below the instance level: every
cluster has an axis-aligned box, a bounding sphere and a normal cone, and the renderer draws
lists of (instance, cluster) pairs (see :mod:`clraster.culling.cull`).

How a mesh is cut (:func:`clusterize`):

1. Faces whose three vertices are finite are sorted by the 30-bit Morton code of their
   centroid (10 bits per axis over the centroids' bounding cube; ties keep face order).
   Faces with a NaN/Inf vertex follow, in face order: they get clusters of their own, with
   infinite bounds and a cone that never culls, so that culling never removes them and the
   renderer still drops and counts them.
2. That sequence is cut into chunks of ``max_triangles``; a chunk whose triangles use more
   than ``max_vertices`` distinct vertices is cut greedily into the longest prefixes that
   fit (every triangle adds at most 3 vertices, so a chunk makes at most
   ``ceil(max_triangles / (max_vertices // 3))`` clusters). A cluster never crosses a chunk
   boundary, so the work is vectorized over chunks with a handful of rounds.

Sizes. The device side runs one work-item per (cluster, local triangle) and per (cluster,
local vertex), so both limits must stay <= 128 there (local indices are uint8 here, which
allows up to 256). Measured on stanford_dragon_vrip.ply (871,414 triangles; this 2-core
host, NumPy 2.4): clusterize time (best of 3), then ``build_draw_list`` host time (best of
20) and the share of triangles removed, for a view framing the whole model ("full") and a
close-up from 8 cm ("close", 69-71 % of the triangles outside the frustum):

    =======  ========  =========  =========  ==========  =======  =======  ========  =======
    limits   clusters  tris/clu   verts/tri  clusterize  full ms  full     close ms  close
                                                                  cone %             cone %
    =======  ========  =========  =========  ==========  =======  =======  ========  =======
    32/32      35,264     24.7       1.00      0.53 s      1.98     34.0      3.85      12.9
    64/64      13,996     62.3       0.84      0.42 s      0.51     27.6      1.80      12.1
    128/128     6,814    127.9       0.74      0.41 s      0.33     21.6      1.18      10.8
    =======  ========  =========  =========  ==========  =======  =======  ========  =======

(verts/tri: cluster-local vertices per triangle, the vertex-stage work per triangle, since a
vertex shared by k clusters is transformed k times.) Smaller clusters let the cones remove
more back faces (+6 points at 64) but cost more vertex work (+13 % at 64, +35 % at 32) and
more host time per frame; 128/128 keeps duplication and host cost lowest and fills a
128-wide work-group per cluster, so it is the default. (At 32 triangles the 32-vertex limit
binds first: 24.7 triangles per cluster.) A 10M-triangle mesh clusterizes in about 4.5 s.

Normal cones (after the idea of meshoptimizer's ``meshopt_computeClusterBounds``; the
formulas and the conservative test below are derived here). See :func:`cone_backfacing`.
"""

from __future__ import annotations

import weakref
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..world.mesh import Mesh

__all__ = ["CONE_NEVER", "CONE_ROWS", "ClusteredMesh", "clusterize", "clusters_of",
           "cone_backfacing", "cone_kernel", "cone_table"]

#: ``cone_cutoff`` of a cluster whose cone never culls (no usable normal, half-angle
#: >= 90°, or a NaN/Inf vertex). Any value > 1 works: a cosine of unit vectors never exceeds 1.
CONE_NEVER = np.float32(2.0)

#: A face whose normal has ``|(b − a) × (c − a)| <= DEGENERATE_SIN · |b − a| · |c − a|`` (the
#: sine of its angle at ``a``) has no reliable orientation and does not shape the cone.
#: Above it, the float64 normal's direction is accurate to about 4.4e-16 / 1e-8 < 1e-7 rad
#: (each cross-product component of exact float64 edge differences is off by at most
#: ~4 ulp of ``|b − a| · |c − a|``).
DEGENERATE_SIN = 1e-8
#: Added to every cone half-angle: covers the normal-direction error above and the float64
#: rounding in the axis/angle computation.
_ANGLE_SLACK = 2e-7

_MAX_LIMIT = 256  # local vertex indices are uint8
#: Chunks per batch in clusterize: temporaries stay cache-sized (4096 was 1.5x slower).
_CHUNK_ROWS = 1 << 9


@dataclass(frozen=True)
class ClusteredMesh:
    """A mesh split into spatially coherent clusters (meshlets).

    Each cluster has <= ``max_triangles`` triangles and <= ``max_vertices`` unique vertices.
    ``C`` = ``n_clusters``, ``M`` = the mesh's face count. All arrays are read-only.

    Attributes:
        n_clusters: C.
        tri_offset: int32 (C + 1,): cluster c owns the clustered triangles
            ``tri_offset[c]:tri_offset[c + 1]`` (rows of `local_tris` / `face_ids`).
        vert_offset: int32 (C + 1,): cluster c's local vertices are
            ``vert_ids[vert_offset[c]:vert_offset[c + 1]]``.
        vert_ids: int32 (vert_offset[-1],): the mesh vertex index of each cluster-local
            vertex, in order of first use by the cluster's triangles.
        local_tris: uint8 (M, 3): local vertex indices (< max_vertices) of each clustered
            triangle: ``vert_ids[vert_offset[c] + local_tris[t]] == faces[face_ids[t]]`` for
            t in cluster c, same vertex order (winding) as the face.
        face_ids: int32 (M,): the original face index of each clustered triangle, a
            permutation of 0..M-1. Finite faces come first (Morton order of centroids),
            faces with a NaN/Inf vertex last (face order).
        aabb_min, aabb_max: float32 (C, 3): object-space box of the cluster's vertices
            (exact: min/max of float32 values). −inf / +inf for clusters with a NaN/Inf
            vertex (`bounded` False).
        sphere: float32 (C, 4): centre xyz and radius; every vertex of the cluster is within
            the radius of the centre (radius rounded up to float32). (0, 0, 0, +inf) for
            unbounded clusters.
        cone_apex: float32 (C, 3): a point behind the plane of every (non-degenerate)
            triangle of the cluster: ``dot(n_t, p − apex) >= 0`` for all points p of t.
        cone_axis: float32 (C, 3): unit axis; every non-degenerate face normal is within
            the half-angle α of it.
        cone_cutoff: float32 (C,): ``sin(α)``, rounded up; `CONE_NEVER` (2.0) where the
            cone never culls. In meshoptimizer's terms the cluster faces away (without
            margin) from an eye e when ``dot(normalize(apex − e), axis) >= cutoff``;
            :func:`cone_backfacing` is the conservative test with a margin.
        max_triangles, max_vertices: the limits it was built with.
    """

    n_clusters: int
    tri_offset: np.ndarray
    vert_offset: np.ndarray
    vert_ids: np.ndarray
    local_tris: np.ndarray
    face_ids: np.ndarray
    aabb_min: np.ndarray
    aabb_max: np.ndarray
    sphere: np.ndarray
    cone_apex: np.ndarray
    cone_axis: np.ndarray
    cone_cutoff: np.ndarray
    max_triangles: int = 128
    max_vertices: int = 128

    @property
    def n_triangles(self) -> np.ndarray:
        """int32 (C,): triangles per cluster."""
        return np.diff(self.tri_offset)

    @property
    def n_vertices(self) -> np.ndarray:
        """int32 (C,): local vertices per cluster."""
        return np.diff(self.vert_offset)

    @property
    def bounded(self) -> np.ndarray:
        """bool (C,): the cluster's bounds are finite (all its vertices are finite)."""
        return np.isfinite(self.aabb_min).all(axis=1) & np.isfinite(self.aabb_max).all(axis=1)

    def __repr__(self) -> str:
        return (f"ClusteredMesh(n_clusters={self.n_clusters}, "
                f"n_triangles={int(self.tri_offset[-1])}, "
                f"max_triangles={self.max_triangles}, max_vertices={self.max_vertices})")


# -- building ---------------------------------------------------------------------------

def _check_limits(max_triangles: int, max_vertices: int) -> tuple[int, int]:
    for name, v, lo in (("max_triangles", max_triangles, 1), ("max_vertices", max_vertices, 3)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= _MAX_LIMIT:
            raise ValueError(f"{name} must be an integer in {lo}..{_MAX_LIMIT} (local indices "
                             f"are uint8; the OpenCL side expects <= 128), got {v!r}")
    return int(max_triangles), int(max_vertices)


def _spread10(x: np.ndarray) -> np.ndarray:
    """Spread the low 10 bits of uint32 `x` to every third bit (Morton interleave)."""
    x = x & np.uint32(0x3FF)
    x = (x | (x << np.uint32(16))) & np.uint32(0x30000FF)
    x = (x | (x << np.uint32(8))) & np.uint32(0x300F00F)
    x = (x | (x << np.uint32(4))) & np.uint32(0x30C30C3)
    x = (x | (x << np.uint32(2))) & np.uint32(0x9249249)
    return x


def _morton_order(centroids: list[np.ndarray], ids: np.ndarray) -> np.ndarray:
    """`ids` sorted by the 30-bit Morton code of the points (x, y, z columns) `centroids`,
    quantized over their bounding cube (ties: by id)."""
    if ids.size == 0:
        return ids
    lo = [float(c.min()) for c in centroids]
    extent = max(float(c.max()) - m for c, m in zip(centroids, lo, strict=True))
    scale = 1023.999 / extent if extent > 0 else 0.0
    code = np.zeros(ids.size, dtype=np.uint32)
    for k, (c, m) in enumerate(zip(centroids, lo, strict=True)):
        q = np.clip((c.astype(np.float64) - m) * scale, 0.0, 1023.0).astype(np.uint32)
        code |= _spread10(q) << np.uint32(k)
    key = (code.astype(np.uint64) << np.uint64(33)) | ids.astype(np.uint64)  # unique keys
    return (np.sort(key) & np.uint64((1 << 33) - 1)).astype(np.int32)


def _split_rows(vals: np.ndarray, n_tri: np.ndarray, max_vertices: int):
    """Cut each row (a chunk of triangles) into clusters of <= max_vertices vertices.

    Args:
        vals: int64 (R, 3T): vertex ids of the chunk's triangles, row-major; padding past
            ``3 * n_tri[r]`` holds a sentinel larger than every vertex id.
        n_tri: int64 (R,): triangles per row (>= 1).

    Returns:
        seg_len: int64: triangles per cluster, clusters in (row, start) order.
        local: int32 (R, 3T): local vertex index of each entry (undefined in padding).
        first: bool (R, 3T): the entry is the first use of its vertex in its cluster.
    """
    n_rows, width = vals.shape
    n_slots = width // 3
    shift = int(width - 1).bit_length()
    pos = np.arange(width, dtype=np.int32)
    # Sort (vertex, position) pairs per row: a stable arg-sort by vertex, through one sort.
    keys = np.sort((vals << shift) | pos, axis=1)
    same = np.zeros(keys.shape, dtype=bool)
    same[:, 1:] = (keys[:, 1:] >> shift) == (keys[:, :-1] >> shift)
    sp = (keys & ((1 << shift) - 1)).astype(np.int32)
    del keys
    # Flat index of each sorted entry's position, for scatters back to position order.
    flat = (np.arange(n_rows, dtype=np.int64) * width)[:, None] + sp
    # prev[r, j]: position of the previous use of the same vertex in row r, or −1.
    prev_sorted = np.full(sp.shape, -1, dtype=np.int32)
    prev_sorted[:, 1:] = np.where(same[:, 1:], sp[:, :-1], -1)
    prev = np.empty(sp.shape, dtype=np.int32)
    prev.ravel()[flat.ravel()] = prev_sorted.ravel()
    del prev_sorted

    # Greedy rounds: each row's next cluster is the longest run of triangles from `start`
    # whose entries introduce at most max_vertices new vertices.
    valid = pos[None, :] < 3 * n_tri[:, None]
    start = np.zeros(n_rows, dtype=np.int64)
    seg_rows: list[np.ndarray] = []
    seg_starts: list[np.ndarray] = []
    seg_lens: list[np.ndarray] = []
    active = np.arange(n_rows)
    tri = np.arange(n_slots)[None, :]
    while active.size:
        st = start[active][:, None]
        new = (prev[active] < 3 * st) & (pos[None, :] >= 3 * st) & valid[active]
        count = np.cumsum(new, axis=1, dtype=np.int32)[:, 2::3]  # new vertices up to tri t
        fits = (tri >= st) & (tri < n_tri[active][:, None]) & (count <= max_vertices)
        k = fits.sum(axis=1)  # count is monotone in t, so the fitting ones are a prefix
        seg_rows.append(active)
        seg_starts.append(start[active].copy())
        seg_lens.append(k)
        start[active] += k
        active = active[start[active] < n_tri[active]]
    seg_row = np.concatenate(seg_rows)
    seg_start = np.concatenate(seg_starts)
    seg_len = np.concatenate(seg_lens)
    order = np.argsort(seg_row * n_slots + seg_start)
    seg_row, seg_start, seg_len = seg_row[order], seg_start[order], seg_len[order]

    # Entry offset of the cluster start for every position (a running max per row spreads
    # each cluster's start over its range; the first cluster of a row starts at 0).
    marks = np.zeros(n_rows * n_slots, dtype=np.int32)
    marks[seg_row * n_slots + seg_start] = 3 * seg_start
    seg_entry_start = np.repeat(np.maximum.accumulate(marks.reshape(n_rows, n_slots), axis=1),
                                3, axis=1)
    first = (prev < seg_entry_start) & valid
    del prev
    # Local index of a first use: its rank among first uses in its cluster.
    cum = np.cumsum(first, axis=1, dtype=np.int32)
    row_base = (np.arange(n_rows, dtype=np.int64) * width)[:, None]
    before_start = (seg_entry_start + row_base - 1).ravel()
    base = np.where(seg_entry_start.ravel() > 0, cum.ravel()[np.maximum(before_start, 0)], 0)
    local_first = cum.ravel() - 1 - base  # flat, position order
    # Other entries copy the local index of their run's first entry: in sorted order a run
    # is a maximal sequence of the same vertex within one cluster.
    seg_sorted = seg_entry_start.ravel()[flat.ravel()].reshape(n_rows, width)
    run_start = np.ones(same.shape, dtype=bool)
    run_start[:, 1:] = ~same[:, 1:] | (seg_sorted[:, 1:] != seg_sorted[:, :-1])
    del same, seg_sorted
    idx = np.maximum.accumulate(np.where(run_start, pos[None, :], 0), axis=1)
    first_flat = flat.ravel()[(idx + row_base).ravel()]
    local = np.empty(n_rows * width, dtype=np.int32)
    local[flat.ravel()] = local_first[first_flat]
    return seg_len, local.reshape(n_rows, width), first


def clusterize(mesh: Mesh, max_triangles: int = 128, max_vertices: int = 128) -> ClusteredMesh:
    """Split `mesh` into clusters of <= `max_triangles` triangles and <= `max_vertices`
    unique vertices, with bounds and normal cones. See the module docstring for the method.

    Deterministic (no randomness; ties broken by face index). About 0.4 s for 871K
    triangles and 4.5 s for 10M on a 2-core host.

    Args:
        mesh: a `clraster.Mesh`; M = 0 gives a ClusteredMesh with no cluster.
        max_triangles: 1..256 (the OpenCL side expects <= 128).
        max_vertices: 3..256 (the OpenCL side expects <= 128).

    Raises:
        ValueError: limits out of range.
    """
    max_triangles, max_vertices = _check_limits(max_triangles, max_vertices)
    verts = np.asarray(mesh.vertices)
    faces = np.asarray(mesh.faces)
    n_faces = faces.shape[0]
    if n_faces == 0:
        return _empty(max_triangles, max_vertices)

    # Structure-of-arrays float64 copies: column arithmetic is much faster than (n, 3) rows.
    cols = [np.ascontiguousarray(verts[:, k], dtype=np.float64) for k in range(3)]
    fcols = [np.ascontiguousarray(faces[:, k]) for k in range(3)]
    finite_v = np.isfinite(cols[0]) & np.isfinite(cols[1]) & np.isfinite(cols[2])
    finite_f = finite_v[fcols[0]] & finite_v[fcols[1]] & finite_v[fcols[2]]
    good = np.flatnonzero(finite_f).astype(np.int32)
    bad = np.flatnonzero(~finite_f).astype(np.int32)
    g = fcols if bad.size == 0 else [f[good] for f in fcols]
    # 3 × the centroid, in float32 (only quantized to 10 bits per axis).
    v32 = [np.ascontiguousarray(verts[:, k]) for k in range(3)]
    with np.errstate(over="ignore"):
        centroid_sums = [c[g[0]] + c[g[1]] + c[g[2]] for c in v32]
    if not all(np.isfinite(c).all() for c in centroid_sums):  # float32 overflow: redo
        centroid_sums = [c[g[0]] + c[g[1]] + c[g[2]] for c in cols]
    del g, v32
    face_seq = np.concatenate([_morton_order(centroid_sums, good), bad])
    del centroid_sums, fcols, finite_v, finite_f

    # Chunks of max_triangles: finite faces first, then the non-finite ones.
    t = max_triangles
    starts = np.concatenate([np.arange(0, good.size, t), good.size + np.arange(0, bad.size, t)])
    ends = np.minimum(np.append(starts[1:], n_faces), n_faces)
    ends[(starts < good.size) & (ends > good.size)] = good.size
    n_tri = (ends - starts).astype(np.int64)
    # Within a chunk keep the caller's face order (Morton order only picks the members): a
    # mesh of <= max_triangles faces is then drawn exactly in index order, and bigger ones
    # in index order within each cluster. (Ties never depend on it — the depth test breaks
    # them by triangle id — but per-fragment statistics such as depth-test passes do.)
    # (Sorted row by row in the padded (chunk, slot) grid; the padding sorts last.)
    n_chunks = starts.size
    chunk_of_face = np.repeat(np.arange(n_chunks), n_tri)
    slot = np.arange(n_faces) - starts[chunk_of_face]
    dest_face = chunk_of_face * t + slot  # face position in the padded (chunk, slot) grid
    pad = np.iinfo(np.int32).max
    grid = np.full(n_chunks * t, pad, np.int32)
    grid[dest_face] = face_seq
    grid = np.sort(grid.reshape(n_chunks, t), axis=1).ravel()
    face_seq = grid[grid != pad]
    del grid

    # Padded (chunk, 3·max_triangles) matrix of vertex ids, processed in batches of chunks.
    sentinel = np.int64(verts.shape[0])
    seq_verts = faces[face_seq]
    seg_len_all, local_all, first_all, vid_all = [], [], [], []
    for r0 in range(0, n_chunks, _CHUNK_ROWS):
        r1 = min(r0 + _CHUNK_ROWS, n_chunks)
        f0, f1 = int(starts[r0]), int(ends[r1 - 1])
        vals = np.full(((r1 - r0) * t, 3), sentinel, dtype=np.int64)
        vals[dest_face[f0:f1] - r0 * t] = seq_verts[f0:f1]
        vals = vals.reshape(r1 - r0, 3 * t)
        seg_len, local, first = _split_rows(vals, n_tri[r0:r1], max_vertices)
        valid = (vals != sentinel).ravel()
        seg_len_all.append(seg_len)
        local_all.append(local.ravel()[valid])
        first_all.append(first.ravel()[valid])
        vid_all.append(vals.ravel()[valid])
    del seq_verts, dest_face, slot, chunk_of_face
    seg_len = np.concatenate(seg_len_all)
    local = np.concatenate(local_all)
    first = np.concatenate(first_all)
    vids = np.concatenate(vid_all)
    del seg_len_all, local_all, first_all, vid_all

    n_clusters = int(seg_len.size)
    tri_offset = np.zeros(n_clusters + 1, dtype=np.int64)
    np.cumsum(seg_len, out=tri_offset[1:])
    cluster_of_entry = np.repeat(np.arange(n_clusters), 3 * seg_len)
    n_local = np.bincount(cluster_of_entry[first], minlength=n_clusters)
    vert_offset = np.zeros(n_clusters + 1, dtype=np.int64)
    np.cumsum(n_local, out=vert_offset[1:])
    vert_ids = vids[first].astype(np.int32)
    local_tris = local.reshape(-1, 3).astype(np.uint8)

    bounded = np.ones(n_clusters, dtype=bool)
    bounded[tri_offset[:-1] >= good.size] = False  # clusters made of non-finite faces
    # Clusters of non-finite faces (not `bounded`) get NaN/Inf bounds and cones that no test
    # ever reads (they are always drawn); NumPy's warnings about them would only leak into
    # the caller's output.
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        aabb_min, aabb_max, sphere, apex, axis, cutoff = _geometry(
            cols, faces, face_seq, tri_offset, vert_ids, vert_offset, bounded)

    return _frozen(ClusteredMesh(
        n_clusters=n_clusters,
        tri_offset=tri_offset.astype(np.int32),
        vert_offset=vert_offset.astype(np.int32),
        vert_ids=vert_ids,
        local_tris=local_tris,
        face_ids=face_seq.astype(np.int32),
        aabb_min=aabb_min, aabb_max=aabb_max, sphere=sphere,
        cone_apex=apex, cone_axis=axis, cone_cutoff=cutoff,
        max_triangles=max_triangles, max_vertices=max_vertices))


def _empty(max_triangles: int, max_vertices: int) -> ClusteredMesh:
    z3 = np.zeros((0, 3), np.float32)
    return _frozen(ClusteredMesh(
        0, np.zeros(1, np.int32), np.zeros(1, np.int32), np.zeros(0, np.int32),
        np.zeros((0, 3), np.uint8), np.zeros(0, np.int32), z3, z3.copy(),
        np.zeros((0, 4), np.float32), z3.copy(), z3.copy(), np.zeros(0, np.float32),
        max_triangles, max_vertices))


def _frozen(cm: ClusteredMesh) -> ClusteredMesh:
    for value in vars(cm).values():
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    return cm


def _round_up32(x: np.ndarray) -> np.ndarray:
    """float64 → float32, rounded towards +inf (beyond float32 range: +inf)."""
    with np.errstate(over="ignore"):
        y = x.astype(np.float32)
    low = y.astype(np.float64) < x
    y[low] = np.nextafter(y[low], np.float32(np.inf))
    return y


_BATCH_TRIANGLES = 1 << 16  # triangles per batch in _geometry (keeps temporaries in cache)


def _geometry(cols: list[np.ndarray], faces: np.ndarray, face_seq: np.ndarray,
              tri_offset: np.ndarray, vert_ids: np.ndarray, vert_offset: np.ndarray,
              bounded: np.ndarray):
    """Bounds and normal cones of every cluster, in batches of clusters.

    Returns aabb_min, aabb_max (float32 (C, 3)), sphere (float32 (C, 4)), cone_apex,
    cone_axis (float32 (C, 3)) and cone_cutoff (float32 (C,)); see `ClusteredMesh`.
    """
    n = bounded.size
    lo = np.empty((n, 3), np.float32)
    hi = np.empty((n, 3), np.float32)
    sphere = np.empty((n, 4), np.float32)
    apex = np.empty((n, 3), np.float32)
    axis = np.empty((n, 3), np.float32)
    cutoff = np.empty(n, np.float32)
    # Cluster batches of about _BATCH_TRIANGLES triangles.
    cuts = np.searchsorted(tri_offset, np.arange(0, int(tri_offset[-1]), _BATCH_TRIANGLES))
    cuts = np.unique(np.append(np.minimum(cuts, n), n))
    cuts = cuts[cuts > 0] if cuts.size and cuts[0] == 0 else cuts
    c0 = 0
    for c1 in cuts.tolist():
        if c1 <= c0:
            continue
        sl = slice(c0, c1)
        v0, v1 = int(vert_offset[c0]), int(vert_offset[c1])
        t0, t1 = int(tri_offset[c0]), int(tri_offset[c1])
        vstarts = vert_offset[c0:c1] - v0
        tstarts = tri_offset[c0:c1] - t0
        ok_b = bounded[sl]
        p = [c[vert_ids[v0:v1]] for c in cols]
        b_lo, b_hi, b_sphere = _bounds(p, vstarts, ok_b)
        tri = faces[face_seq[t0:t1]]
        corners = [[c[tri[:, j]] for c in cols] for j in range(3)]  # [vertex][axis] columns
        b_apex, b_axis, b_cutoff = _cones(corners, tstarts, b_sphere, ok_b)
        lo[sl], hi[sl], sphere[sl] = b_lo, b_hi, b_sphere
        apex[sl], axis[sl], cutoff[sl] = b_apex, b_axis, b_cutoff
        c0 = c1
    return lo, hi, sphere, apex, axis, cutoff


def _bounds(p: list[np.ndarray], starts: np.ndarray, bounded: np.ndarray):
    """AABB (exact float32 min/max) and sphere (AABB centre, radius rounded up) per cluster
    from the x, y, z columns `p` of the clusters' local vertices."""
    n = bounded.size
    lo = np.empty((n, 3), np.float32)
    hi = np.empty((n, 3), np.float32)
    centre = np.empty((n, 3), np.float32)
    counts = np.diff(np.append(starts, p[0].size))
    d2 = np.zeros(p[0].size)
    with np.errstate(invalid="ignore", over="ignore"):
        for k in range(3):
            lo64 = np.minimum.reduceat(p[k], starts)
            hi64 = np.maximum.reduceat(p[k], starts)
            lo[:, k] = lo64  # the inputs are float32 values: exact
            hi[:, k] = hi64
            centre[:, k] = (lo64 + hi64) / 2.0
            d2 += (p[k] - np.repeat(centre[:, k].astype(np.float64), counts)) ** 2
        radius = np.sqrt(np.maximum.reduceat(d2, starts))
    lo[~bounded] = -np.inf
    hi[~bounded] = np.inf
    centre[~bounded] = 0.0
    radius[~bounded] = np.inf
    sphere = np.empty((n, 4), np.float32)
    sphere[:, :3] = centre
    sphere[:, 3] = _round_up32(radius)
    return lo, hi, sphere


def _cones(corners: list[list[np.ndarray]], starts: np.ndarray, sphere: np.ndarray,
           bounded: np.ndarray):
    """Normal cones (apex, unit axis, cutoff = sin α rounded up, or CONE_NEVER).

    `corners[j][k]`: coordinate k (float64) of vertex j of every clustered triangle.

    Axis: the normalized sum of the unit normals of the cluster's non-degenerate faces.
    Half-angle: α = max angle between the stored (float32) axis and those normals, plus
    `_ANGLE_SLACK`. The cone never culls if α >= 90°, no face is usable, or the cluster has
    a NaN/Inf vertex.

    Apex: A = centre − τ·axis with the smallest τ that puts A behind (or on) every
    triangle's plane: h_t = dot(n_t, p_t − A) = dot(n_t, p_t − c) + τ·dot(n_t, axis) >= 0,
    i.e. τ >= −dot(n_t, p_t − c) / dot(n_t, axis) (dot(n_t, axis) >= cos α > 0). After the
    apex is rounded to float32, h_t is checked again in float64 and the apex pushed further
    back along −axis where rounding broke it.
    """
    n = bounded.size
    a = corners[0]
    e1 = [corners[1][k] - a[k] for k in range(3)]
    e2 = [corners[2][k] - a[k] for k in range(3)]
    with np.errstate(invalid="ignore", over="ignore"):
        nrm = [e1[1] * e2[2] - e1[2] * e2[1],
               e1[2] * e2[0] - e1[0] * e2[2],
               e1[0] * e2[1] - e1[1] * e2[0]]
        length = np.sqrt(nrm[0] ** 2 + nrm[1] ** 2 + nrm[2] ** 2)
        scale = np.sqrt((e1[0] ** 2 + e1[1] ** 2 + e1[2] ** 2)
                        * (e2[0] ** 2 + e2[1] ** 2 + e2[2] ** 2))
        usable = np.isfinite(length) & np.isfinite(scale) & (length > DEGENERATE_SIN * scale)
        inv = np.where(usable, 1.0 / np.where(usable, length, 1.0), 0.0)
    unit = [np.where(usable, nrm[k], 0.0) * inv for k in range(3)]
    del e1, e2, nrm, length, scale, inv
    counts = np.diff(np.append(starts, usable.size))

    total = np.stack([np.add.reduceat(unit[k], starts) for k in range(3)], axis=1)
    tlen = np.linalg.norm(total, axis=1)
    has_axis = bounded & (tlen > 0)
    axis = np.zeros((n, 3), np.float32)
    axis[:, 2] = 1.0
    axis[has_axis] = (total[has_axis] / tlen[has_axis, None]).astype(np.float32)
    ax64 = axis.astype(np.float64)
    ax64 /= np.linalg.norm(ax64, axis=1)[:, None]
    ax_t = [np.repeat(ax64[:, k], counts) for k in range(3)]

    cos_t = unit[0] * ax_t[0] + unit[1] * ax_t[1] + unit[2] * ax_t[2]
    cos_min = np.minimum.reduceat(np.where(usable, cos_t, np.inf), starts)
    ok = has_axis & np.isfinite(cos_min) & (cos_min > 0.0)
    alpha = np.full(n, np.pi)
    alpha[ok] = np.arccos(np.clip(cos_min[ok], -1.0, 1.0)) + _ANGLE_SLACK
    ok &= alpha < np.pi / 2
    cos_alpha = np.cos(np.minimum(alpha, np.pi / 2))

    use_t = usable & np.repeat(ok, counts)
    centre = sphere[:, :3].astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        dot_rel = sum(unit[k] * (a[k] - np.repeat(centre[:, k], counts)) for k in range(3))
        tau_t = np.where(use_t, -dot_rel / np.where(use_t, cos_t, 1.0), -np.inf)
    tau = np.maximum.reduceat(tau_t, starts)
    tau[~ok] = 0.0
    apex = (centre - ax64 * tau[:, None]).astype(np.float32)

    def h_min() -> np.ndarray:
        ap = apex.astype(np.float64)
        with np.errstate(invalid="ignore"):
            h = sum(unit[k] * (a[k] - np.repeat(ap[:, k], counts)) for k in range(3))
        return np.minimum.reduceat(np.where(use_t, h, np.inf), starts)

    for _ in range(4):  # re-check after rounding to float32; push back where needed
        hm = h_min()
        broken = ok & (hm < 0.0)
        if not broken.any():
            break
        push = (-hm[broken] / cos_alpha[broken]) * 2.0 \
            + 1e-6 * np.abs(apex[broken].astype(np.float64)).max(axis=1)
        apex[broken] = (apex[broken].astype(np.float64) - ax64[broken] * push[:, None]) \
            .astype(np.float32)
    else:
        ok &= ~(h_min() < 0.0)
    ok &= np.isfinite(apex).all(axis=1)

    cutoff = np.full(n, CONE_NEVER, np.float32)
    cutoff[ok] = _round_up32(np.sin(alpha[ok]))
    cutoff[ok & (cutoff >= 1.0)] = CONE_NEVER
    apex[~ok] = sphere[~ok, :3]
    apex[~bounded] = 0.0
    return apex, axis, cutoff


# -- the conservative back-facing test --------------------------------------------------

def cone_backfacing(eye: npt.ArrayLike, apex: npt.ArrayLike, axis: npt.ArrayLike,
                    cutoff: npt.ArrayLike, sphere: npt.ArrayLike, *,
                    margin: float | npt.ArrayLike = 1e-3,
                    front: bool | npt.ArrayLike = False) -> np.ndarray:
    """Whether the eye sees the back of every triangle of each cluster, with a margin.

    Conservative: True guarantees, for every non-degenerate triangle t of the cluster (unit
    normal n_t) and every point p of t, ``dot(n_t, u) >= sin(margin)`` where ``u`` is the
    unit vector from the eye to p — the eye is behind the plane of t and sees it at least
    `margin` radians away from edge-on. (Faces whose sine at vertex a is below
    `DEGENERATE_SIN` have no reliable orientation and are not covered.) False means
    "unknown": draw the cluster.

    Args:
        eye: (4,) or (P, 4) homogeneous eye in the clusters' object space. w != 0: a point
            eye at xyz/w. w == 0: an orthographic eye looking along the direction xyz (from
            the camera into the scene): the test is then ``dot(n_t, d) >= sin(margin)``.
        apex, axis, cutoff, sphere: (P, 3), (P, 3), (P,), (P, 4) cone and sphere data of
            P clusters (`ClusteredMesh` rows).
        margin: radians, scalar or (P,); 0 gives a plain strict test ``dot(n_t, u) > 0``.
        front: scalar or (P,) bool: test the front side instead (``−n_t`` for n_t; for
            cull="front", or object transforms with a negative determinant).

    Returns:
        bool (P,).

    Derivation (perspective eye e; write s = ±1 for back/front, v = A − e, L = |v|):
    for every point p of triangle t,
        dot(s·n_t, p − e) = s·dot(n_t, p − A) + dot(s·n_t, v) = s·h_t + dot(s·n_t, v).
    The apex A lies behind every triangle plane: 0 <= h_t <= |p − A| <= R, with
    R = |c − A| + r from the bounding sphere (c, r), so s·h_t >= −H with H = 0 for the
    back test and H = R for the front one. The angle between s·n_t and v is at most
    φ = α + γ (triangle inequality on the sphere of directions), with γ the angle between
    s·axis and v, so dot(s·n_t, v) >= L·cos φ when φ <= π. And |p − e| <= L + R. Hence
        L·cos φ − H >= sin(margin)·(L + R)   and   φ < π/2
    implies dot(s·n_t, p − e) >= sin(margin)·|p − e| for all t and p: the claim.
    (φ < π/2 holds iff cos φ > 0, as α < π/2 and γ <= π.) L·cos φ = cos α·L·cos γ −
    sin α·L·sin γ with L·cos γ = dot(s·axis, v) and L·sin γ = sqrt(L² − (L·cos γ)²): no
    arccos, no division. sin α = cutoff was rounded up, so α is never underestimated; the
    float64 rounding of this evaluation (at most ~3e-8·L, from the square root) is covered
    by testing against sin(margin) + 1e-7 instead of sin(margin).
    Orthographic (unit direction d): the angle between s·n_t and d is at most
    φ = α + angle(s·axis, d), so cos φ >= sin(margin) implies the claim.
    """
    apex = np.asarray(apex, dtype=np.float64).reshape(-1, 3)
    n = apex.shape[0]
    data = cone_table(apex, np.asarray(axis, dtype=np.float64).reshape(n, 3),
                      np.asarray(cutoff, dtype=np.float64).reshape(n),
                      np.asarray(sphere, dtype=np.float64).reshape(n, 4))
    eye = np.broadcast_to(np.asarray(eye, dtype=np.float64), (n, 4))
    sin_m = np.broadcast_to(np.sin(np.asarray(margin, dtype=np.float64)), (n,))
    side = np.where(np.broadcast_to(np.asarray(front, dtype=bool), (n,)), -1.0, 1.0)
    out = np.zeros(n, dtype=bool)
    ok_eye = np.isfinite(eye).all(axis=1)
    persp = ok_eye & (eye[:, 3] != 0.0)
    ortho = ok_eye & (eye[:, 3] == 0.0)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        if persp.any():
            e = eye[persp, :3] / eye[persp, 3:4]
            out[persp] = cone_kernel(data[:, persp], e.T, side[persp], sin_m[persp], False)
        if ortho.any():
            d = eye[ortho, :3]
            dlen = np.linalg.norm(d, axis=1)
            good = dlen > 0.0
            d = d / np.where(good, dlen, 1.0)[:, None]
            out[ortho] = good & cone_kernel(data[:, ortho], d.T, side[ortho], sin_m[ortho],
                                            True)
    return out


#: Rows of a cone table (see `cone_table`).
CONE_ROWS = ("apex_x", "apex_y", "apex_z", "axis_x", "axis_y", "axis_z", "cos_alpha",
             "sin_alpha", "reach")
#: Added to sin(margin) in `cone_kernel`: covers its own float64 rounding (the sine of the
#: axis-to-eye angle comes from sqrt(L² − dot²), accurate to ~2·sqrt(2**−53)·L).
_KERNEL_SLACK = 1e-7


def cone_table(apex: np.ndarray, axis: np.ndarray, cutoff: np.ndarray,
               sphere: np.ndarray) -> np.ndarray:
    """float64 (9, P) structure-of-arrays cone data for `cone_kernel` (rows `CONE_ROWS`).

    The axis is renormalized in float64; cos α = sqrt(1 − cutoff²); reach = |c − apex| + r
    bounds the distance from the apex to any point of the cluster. Clusters whose cone
    never culls (cutoff outside [0, 1), a zero axis, NaN/Inf data) get cos α = 0,
    sin α = 1, which no eye passes, and finite placeholders elsewhere.
    """
    n = apex.shape[0]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        alen = np.linalg.norm(axis, axis=1)
        usable = (cutoff >= 0.0) & (cutoff < 1.0) & (alen > 0.0) \
            & np.isfinite(apex).all(axis=1) & np.isfinite(sphere).all(axis=1) \
            & np.isfinite(alen)
        t = np.empty((9, n))
        t[0:3] = np.where(usable[:, None], apex, 0.0).T
        t[3:6] = np.where(usable[:, None], axis / np.where(usable, alen, 1.0)[:, None],
                          (0.0, 0.0, 1.0)).T
        sin_a = np.where(usable, cutoff, 1.0)
        t[6] = np.sqrt(1.0 - sin_a * sin_a)
        t[7] = sin_a
        t[8] = np.where(usable, np.linalg.norm(sphere[:, :3] - apex, axis=1) + sphere[:, 3], 0.0)
    return t


def cone_kernel(table: np.ndarray, eye: np.ndarray, side: np.ndarray | float,
                sin_margin: np.ndarray | float, orthographic: bool) -> np.ndarray:
    """The test of `cone_backfacing` on a cone table, with NumPy broadcasting.

    Args:
        table: (9, ...) rows `CONE_ROWS` (e.g. (9, C) for all clusters, or gathered
            (9, P) per pair; (9, 1, C) against eyes of shape (3, Q, 1) for a dense Q × C
            evaluation).
        eye: (3, ...) eye point (perspective) or unit viewing direction (orthographic),
            broadcastable against ``table[0]``.
        side: +1 (back test) or −1 (front test), broadcastable.
        sin_margin: sin(margin), broadcastable.

    Returns:
        bool, the broadcast shape.
    """
    ax, ay, az, ux, uy, uz, cos_a, sin_a, reach = table
    sin_m = sin_margin + _KERNEL_SLACK
    if orthographic:
        dv = ux * eye[0] + uy * eye[1] + uz * eye[2]
        sin_g = np.sqrt(np.maximum(1.0 - dv * dv, 0.0))
        cos_phi = cos_a * (side * dv) - sin_a * sin_g
        return cos_phi > sin_m
    vx = ax - eye[0]
    vy = ay - eye[1]
    vz = az - eye[2]
    l2 = vx * vx + vy * vy + vz * vz
    dv = ux * vx + uy * vy + uz * vz
    l_sin_g = np.sqrt(np.maximum(l2 - dv * dv, 0.0))
    l_cos_phi = cos_a * (side * dv) - sin_a * l_sin_g
    # front test (side −1): the apex is behind the planes, so allow h_t up to reach.
    lhs = l_cos_phi - np.where(np.asarray(side) < 0.0, reach, 0.0)
    return (l_cos_phi > 0.0) & (lhs > sin_m * (np.sqrt(l2) + reach))


# -- cache ------------------------------------------------------------------------------

_WEAK_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
#: Fallback for mesh objects that cannot be weakly referenced: a small LRU that keeps them
#: alive (so their id() is not reused while cached).
_STRONG_CACHE: OrderedDict = OrderedDict()
_STRONG_CACHE_SIZE = 64


def clusters_of(mesh: Mesh, max_triangles: int = 128, max_vertices: int = 128) -> ClusteredMesh:
    """`clusterize(mesh, ...)`, computed once per (mesh object, limits) and cached.

    Meshes are immutable, so the cache is keyed by the object: weakly where the object
    allows weak references (the entry goes with the mesh), otherwise in an LRU of the last
    64 meshes (which then keeps them alive).
    """
    key = _check_limits(max_triangles, max_vertices)
    try:
        per_mesh = _WEAK_CACHE.get(mesh)
        weak = True
    except TypeError:
        weak = False
        entry = _STRONG_CACHE.get(id(mesh))
        per_mesh = entry[1] if entry is not None and entry[0] is mesh else None
    if per_mesh is None:
        per_mesh = {}
        if weak:
            _WEAK_CACHE[mesh] = per_mesh
        else:
            _STRONG_CACHE[id(mesh)] = (mesh, per_mesh)
            while len(_STRONG_CACHE) > _STRONG_CACHE_SIZE:
                _STRONG_CACHE.popitem(last=False)
    elif not weak:
        _STRONG_CACHE.move_to_end(id(mesh))
    cm = per_mesh.get(key)
    if cm is None:
        cm = clusterize(mesh, *key)
        per_mesh[key] = cm
    return cm
