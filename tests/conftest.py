"""Shared fixtures and helpers for the rasterizer tests.

* `renderer_for` / `render_both`: one OpenCL `Renderer` per (width, height, tile_log2),
  built once per session and reused (program builds are slow the first time; the renderer
  keeps its device buffers between frames).
* `MatrixCamera`: a camera that returns a fixed clip matrix, so tests control exactly where
  triangles land (identity view, vertices given in eye space).
* `ndc_to_window` / `window_to_ndc`: the image convention the tests pin: row 0 is the top
  row, pixel (x, y) is sampled at (x + 0.5, y + 0.5), x_win = (x_ndc + 1)/2·W,
  y_win = (1 − y_ndc)/2·H.
* `assert_frames_equal`: the differential check (ids and depth exact, barycentrics close,
  every stat count equal), with a message that points at the first differing pixel.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from clraster import Mesh, RasterConfig

# Property tests draw the same examples on every run (derandomized, no example database):
# CI must not pass or fail by the luck of a seed. HYPOTHESIS_PROFILE=explore draws new
# examples each run (to hunt for failures by hand).
settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))

MESH_DIR = Path(__file__).resolve().parents[2] / "shared" / "meshes"

TILE_LOG2S = (3, 4, 5, 6)


class MatrixCamera:
    """Any object with ``view_projection(width, height)`` is a camera: this one returns a
    fixed (4, 4) world → clip matrix whatever the image size."""

    def __init__(self, matrix: np.ndarray) -> None:
        self.matrix = np.asarray(matrix, dtype=np.float64)

    def view_projection(self, width: int, height: int) -> np.ndarray:
        return self.matrix


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """gluPerspective, written out here independently of clraster.camera (float64)."""
    f = 1.0 / math.tan(math.radians(fov_y_deg) / 2.0)
    p = np.zeros((4, 4))
    p[0, 0] = f / aspect
    p[1, 1] = f
    p[2, 2] = (far + near) / (near - far)
    p[2, 3] = 2.0 * far * near / (near - far)
    p[3, 2] = -1.0
    return p



def ortho(left, right, bottom, top, near, far) -> np.ndarray:
    """glOrtho, written out here independently of clraster (float64)."""
    m = np.eye(4)
    m[0, 0] = 2.0 / (right - left)
    m[1, 1] = 2.0 / (top - bottom)
    m[2, 2] = -2.0 / (far - near)
    m[0, 3] = -(right + left) / (right - left)
    m[1, 3] = -(top + bottom) / (top - bottom)
    m[2, 3] = -(far + near) / (far - near)
    return m


def assert_same_image(on, off, context: str, what: str = "culling") -> None:
    """Two frames of the same view that must be the same image (``what`` on vs off: culling,
    occlusion culling, batching...): ids and depth identical, barycentrics within 1e-6. The
    message names the first differing pixel."""
    diff = on.triangle_id != off.triangle_id
    if diff.any():
        ys, xs = np.nonzero(diff)
        y, x = int(ys[0]), int(xs[0])
        raise AssertionError(
            f"{context}: {what} changed {int(diff.sum())} triangle id(s); first at "
            f"(x={x}, y={y}): on {int(on.triangle_id[y, x])} vs off {int(off.triangle_id[y, x])}"
            f" (depth {on.depth[y, x]!r} vs {off.depth[y, x]!r})")
    bad = on.depth != off.depth
    if bad.any():
        ys, xs = np.nonzero(bad)
        y, x = int(ys[0]), int(xs[0])
        raise AssertionError(f"{context}: {what} changed depth at {int(bad.sum())} pixel(s); "
                             f"first at (x={x}, y={y}): {on.depth[y, x]!r} vs "
                             f"{off.depth[y, x]!r}")
    err = np.abs(on.barycentrics.astype(np.float64) - off.barycentrics)
    assert err.size == 0 or err.max() <= 1e-6, f"{context}: barycentrics differ by {err.max()}"

#: Identity clip matrix: vertices are clip-space (x, y, z) with w = 1, i.e. NDC directly.
NDC_CAMERA = MatrixCamera(np.eye(4))


def window_to_ndc(xw, yw, width: int, height: int):
    """Window (pixels, y down, row 0 at the top) → NDC (y up)."""
    xw = np.asarray(xw, dtype=np.float64)
    yw = np.asarray(yw, dtype=np.float64)
    return xw / width * 2.0 - 1.0, 1.0 - yw / height * 2.0


def ndc_to_window(xn, yn, width: int, height: int):
    xn = np.asarray(xn, dtype=np.float64)
    yn = np.asarray(yn, dtype=np.float64)
    return (xn + 1.0) * 0.5 * width, (1.0 - yn) * 0.5 * height


def window_mesh(tris_win, width: int, height: int, z: float = 0.0) -> Mesh:
    """A mesh for NDC_CAMERA from triangles given in window pixels: (T, 3, 2) → one face
    per triangle, in the given vertex order, all at NDC depth ``z``.

    Window coordinates that are multiples of 1/256 (with power-of-two sizes) map to NDC and
    back exactly in float32, so these triangles snap to exactly the given positions."""
    t = np.asarray(tris_win, dtype=np.float64).reshape(-1, 3, 2)
    xn, yn = window_to_ndc(t[..., 0], t[..., 1], width, height)
    v = np.stack([xn, yn, np.full_like(xn, z)], axis=-1).reshape(-1, 3)
    return Mesh(v, np.arange(v.shape[0]).reshape(-1, 3))


def pixel_centres(width: int, height: int):
    """Window coordinates (xc, yc), each (H, W) float64, of all pixel centres."""
    yc, xc = np.mgrid[0:height, 0:width] + 0.5
    return xc, yc


_RENDERERS: dict[tuple[int, int, int, bool], object] = {}
#: the tile size the helpers below render with unless told (the product's default)
DEFAULT_TILE_LOG2 = RasterConfig().tile_log2


def get_renderer(width: int, height: int, tile_log2: int | None = None, hiz: bool = True):
    """The session's Renderer for this size, tile size and tile Hi-Z setting (built on
    first use)."""
    from clraster import Renderer

    tile_log2 = DEFAULT_TILE_LOG2 if tile_log2 is None else tile_log2
    key = (width, height, tile_log2, hiz)
    r = _RENDERERS.get(key)
    if r is None:
        r = Renderer(width, height, config=RasterConfig(tile_log2=tile_log2, tile_hiz=hiz))
        _RENDERERS[key] = r
    return r


@pytest.fixture(scope="module")
def client():
    """A Dask client on a LocalCluster of two worker processes (one PoCL thread each), one
    per test module that asks for it (a module that kills a worker leaves the next a fresh
    cluster)."""
    pytest.importorskip("dask.distributed")
    from dask.distributed import Client

    from clraster.scale.distributed import local_cluster

    with local_cluster(2, threads_per_worker=1, pocl_threads=1) as cluster, \
            Client(cluster) as c:
        yield c


@pytest.fixture(scope="session")
def renderer_for():
    """``renderer_for(width, height, tile_log2=None)`` → a cached Renderer (None: the
    default tile size)."""
    return get_renderer


# The core-pipeline tests pin per-triangle counts (every face reaches setup), so they render
# with object culling off; tests/test_culling*.py cover it being on.
def render_cl(mesh, camera, width, height, cull="none", tile_log2=None, culling=False,
              hiz=True):
    return get_renderer(width, height, tile_log2, hiz).render(mesh, camera, cull=cull,
                                                         frustum=culling, cones=culling)


def render_ref(mesh, camera, width, height, cull="none", tile_log2=None, culling=False,
               hiz=True):
    from clraster.pipeline import reference

    tile_log2 = DEFAULT_TILE_LOG2 if tile_log2 is None else tile_log2
    return reference.render(mesh, camera, width, height, cull=cull, frustum=culling,
                            cones=culling,
                            config=RasterConfig(tile_log2=tile_log2, tile_hiz=hiz))


def render_both(mesh, camera, width, height, cull="none", tile_log2=None, culling=False,
                hiz=True):
    """(OpenCL frame, NumPy-twin frame) for the same input and config."""
    return (render_cl(mesh, camera, width, height, cull, tile_log2, culling, hiz),
            render_ref(mesh, camera, width, height, cull, tile_log2, culling, hiz))


def assert_frames_equal(a, b, context: str = "", bary_atol: float = 1e-5,
                        depth_atol: float = 0.0, check_counts: bool = True) -> None:
    """Ids identical, depth equal (exactly by default), barycentrics within ``bary_atol``,
    all stat counts equal."""
    assert a.triangle_id.shape == b.triangle_id.shape, context
    assert a.triangle_id.dtype == np.int32 and b.triangle_id.dtype == np.int32
    assert a.depth.dtype == np.float32 and b.depth.dtype == np.float32
    assert a.barycentrics.dtype == np.float32 and b.barycentrics.dtype == np.float32
    diff = a.triangle_id != b.triangle_id
    if diff.any():
        ys, xs = np.nonzero(diff)
        y, x = int(ys[0]), int(xs[0])
        raise AssertionError(
            f"{context}: triangle ids differ at {int(diff.sum())} pixel(s); first at "
            f"(x={x}, y={y}): {int(a.triangle_id[y, x])} vs {int(b.triangle_id[y, x])} "
            f"(depth {a.depth[y, x]!r} vs {b.depth[y, x]!r})")
    if depth_atol == 0.0:
        bad = a.depth != b.depth
    else:
        bad = np.abs(a.depth.astype(np.float64) - b.depth) > depth_atol
    if bad.any():
        ys, xs = np.nonzero(bad)
        y, x = int(ys[0]), int(xs[0])
        raise AssertionError(
            f"{context}: depth differs at {int(bad.sum())} pixel(s); first at (x={x}, y={y}):"
            f" {a.depth[y, x]!r} vs {b.depth[y, x]!r} (id {int(a.triangle_id[y, x])})")
    np.testing.assert_allclose(a.barycentrics, b.barycentrics, rtol=0, atol=bary_atol,
                               err_msg=f"{context}: barycentrics")
    if check_counts:
        assert a.stats.counts() == b.stats.counts(), f"{context}: stats differ"


def coverage_count(frames) -> np.ndarray:
    """Per-pixel number of frames in which the pixel is covered."""
    return np.sum([f.triangle_id >= 0 for f in frames], axis=0)


def load_shared_mesh(name: str) -> Mesh:
    path = MESH_DIR / name
    if not path.is_file():
        pytest.skip(f"shared mesh {name} not found in {MESH_DIR} (the shared mesh folder "
                    f"next to the repository is absent)")
    return Mesh.load(path)


def pytest_configure(config):
    """SIGINT handled by Python's default handler (KeyboardInterrupt) in the test process,
    whatever it was started with. A test run started in the background by a
    non-interactive shell inherits SIGINT ignored: then ``_thread.interrupt_main()`` (the
    interrupt tests' Ctrl-C) does nothing, and the child processes the Ctrl-C tests start
    (`clraster render`, `clraster view`) inherit it ignored too and never stop. With a
    Python handler here, children start with the default action, as from a terminal."""
    import signal

    if signal.getsignal(signal.SIGINT) in (signal.SIG_IGN, signal.SIG_DFL):
        signal.signal(signal.SIGINT, signal.default_int_handler)
