"""Two views in flight (`RasterConfig.views_in_flight`, `Renderer.view_partner`): the many-view
paths draw every other view with a second renderer in a thread of its own. The frames must be
exactly the one-at-a-time ones, in camera order; failures land at their own view; closing
early or failing leaves no worker behind."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_frames_equal
from test_views import H, W, path_cameras

from clraster import RasterConfig, Renderer
from clraster.base.layout import CLUSTER_MAX
from clraster.scale.batch import iter_views
from clraster.world.examples import example_mesh
from clraster.world.views import ViewError


@pytest.fixture(scope="module")
def mesh():
    return example_mesh()


def workers_alive() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name == "clraster-view" and t.is_alive()]


def one_at_a_time() -> Renderer:
    return Renderer(W, H, config=RasterConfig(views_in_flight=1))


def test_config_checks_views_in_flight():
    for bad in (0, 3, True, 1.5):
        with pytest.raises(ValueError, match="views_in_flight must be 1 or 2"):
            RasterConfig(views_in_flight=bad)


def test_partner_only_where_it_pays(mesh):
    r = Renderer(W, H)
    p = r.view_partner(mesh, {})
    assert p is not None and p is not r and r.view_partner(mesh, {"cull": "none"}) is p
    assert p.queue is not r.queue and p._lock is not r._lock
    assert (p.width, p.height, p.config) == (r.width, r.height, r.config)
    assert r.view_partner(mesh, {"occlusion": True}) is None
    assert one_at_a_time().view_partner(mesh, {}) is None
    # a target over one pass's triangles is device-bound: no second renderer
    assert mesh.n_faces > CLUSTER_MAX
    small = Renderer(W, H, config=RasterConfig(batch_triangles=CLUSTER_MAX))
    assert small.view_partner(mesh, {}) is None


@pytest.mark.parametrize("kw", [{}, {"cull": "none", "reversed_z": True},
                                {"outputs": ("depth", "ids", "normals", "linear_depth")}],
                         ids=["default", "cull-none-reversed", "resolved"])
def test_frames_equal_one_at_a_time_in_order(mesh, kw):
    cams = path_cameras(9)   # 11 views: both renderers draw several, odd count
    expected = list(one_at_a_time().render_many(mesh, cams, **kw))
    r = Renderer(W, H)
    got = list(r.render_many(mesh, cams, **kw))
    # the first view is drawn alone, by the renderer asked; the others by it or its
    # partner, whichever was free (test_partner_draws_while_the_other_is_busy)
    makers = [f.source() for f in got]
    assert makers[0] is r and r._partner is not None and set(makers) <= {r, r._partner}
    assert len(got) == len(expected) == len(cams)
    for k, (a, b) in enumerate(zip(got, expected, strict=True)):
        np.testing.assert_array_equal(a.triangle_id, b.triangle_id, err_msg=f"view {k}")
        np.testing.assert_array_equal(a.depth, b.depth, err_msg=f"view {k}")
        np.testing.assert_array_equal(a.barycentrics, b.barycentrics, err_msg=f"view {k}")
        assert a.stats.counts() == b.stats.counts(), f"view {k}"
        assert a.resolved.keys() == b.resolved.keys()
        for name in a.resolved:
            np.testing.assert_array_equal(a.resolved[name], b.resolved[name],
                                          err_msg=f"view {k} {name}")
    # distinct views really differ, so a shuffled order could not pass
    assert not np.array_equal(got[0].triangle_id, got[1].triangle_id)
    # the same renderer again: its partner is reused, frames the same
    again = list(r.render_many(mesh, cams[:3], **kw))
    for k in range(3):
        np.testing.assert_array_equal(again[k].triangle_id, expected[k].triangle_id)
        np.testing.assert_array_equal(again[k].depth, expected[k].depth)
    assert not workers_alive()


class SlowRenderer(Renderer):
    """A renderer whose frames take 50 ms more (its partner is a plain Renderer)."""

    def render(self, *args, **kwargs):
        time.sleep(0.05)
        return super().render(*args, **kwargs)


def test_partner_draws_while_the_other_is_busy(mesh):
    cams = path_cameras(6)
    r = SlowRenderer(W, H)
    got = list(r.render_many(mesh, cams))
    makers = [f.source() for f in got]
    assert makers[0] is r and makers.count(r._partner) >= 3
    for k, f in enumerate(got):
        assert_frames_equal(f, one_at_a_time().render(mesh, cams[k]), f"view {k}")


def test_a_camera_generator_is_read_one_view_at_a_time(mesh):
    """The next camera chosen from the last frame (a generator fed by the loop): no
    read-ahead, no partner, no hang."""
    cams = path_cameras(3)
    wanted = [cams[0]]

    def next_best_view():
        for k in range(len(cams)):
            yield wanted[k]   # an IndexError here would mean a camera read ahead

    r = Renderer(W, H)
    got = []
    for k, f in enumerate(r.render_many(mesh, next_best_view())):
        got.append(f)
        if k + 1 < len(cams):
            wanted.append(cams[k + 1])
    assert len(got) == len(cams) and r._partner is None
    for k, f in enumerate(got):
        assert_frames_equal(f, one_at_a_time().render(mesh, cams[k]), f"view {k}")
    outs = [v["index"] for v in iter_views(mesh, (c for c in cams), ("ids",),
                                           renderer=Renderer(W, H))]
    assert outs == list(range(len(cams)))


class FailsInRender:
    """A camera whose first projection (the camera list's check) works and whose next
    ones (the render's) fail with an error that is not the view's fault."""

    def __init__(self, cam):
        self.cam, self.calls = cam, 0

    def view_projection(self, width, height):
        self.calls += 1
        if self.calls > 1:
            raise RuntimeError("boom in render")
        return self.cam.view_projection(width, height)


def test_an_error_in_render_lands_at_its_view(mesh):
    cams: list = path_cameras(6)
    cams[4] = FailsInRender(cams[4])
    got = []
    with pytest.raises(RuntimeError, match="boom in render"):
        for f in Renderer(W, H).render_many(mesh, cams):
            got.append(f)
    assert len(got) == 4 and cams[4].calls > 1
    for k in range(4):
        assert_frames_equal(got[k], one_at_a_time().render(mesh, cams[k]), f"view {k}")
    assert not workers_alive()


def test_a_partner_out_of_memory_hands_its_views_back(mesh):
    """The second renderer failing to allocate (MemoryError) costs nothing but speed: its
    view is drawn by the first renderer, the rest one at a time, the partner let go."""
    cams = path_cameras(6)
    r = SlowRenderer(W, H)   # (busy: the partner surely takes a view)
    partner = r.view_partner(mesh, {})
    calls = []

    def no_memory(*args, **kwargs):
        calls.append(1)
        raise MemoryError("a partner's buffer")

    partner.render = no_memory
    got = list(r.render_many(mesh, cams))
    assert len(got) == len(cams) and calls
    for k, f in enumerate(got):
        assert f.source() is r
        assert_frames_equal(f, one_at_a_time().render(mesh, cams[k]), f"view {k}")
    assert r._partner is None and r.view_partner(mesh, {}) is None
    assert not workers_alive()


def test_exit_with_a_generator_alive_is_clean(tmp_path):
    """A script that leaves a half-read render_many behind exits normally: the workers
    are stopped and joined before the interpreter goes (a worker inside OpenCL then
    aborted the process)."""
    script = tmp_path / "live.py"
    script.write_text(textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_views import path_cameras
        from clraster import Renderer
        from clraster.world.examples import example_mesh
        gen = Renderer(320, 240).render_many(example_mesh(), path_cameras(30))
        next(gen), next(gen)
        print("leaving", flush=True)
    """))
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    for _ in range(2):
        proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                              timeout=120, env=env)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert "leaving" in proc.stdout and "terminate called" not in proc.stderr


def test_iter_views_arrays_equal(mesh):
    cams = path_cameras(5)
    outs = ("linear_depth", "normals", "mask", "ids")
    seq = list(iter_views(mesh, cams, outs, renderer=one_at_a_time()))
    two = list(iter_views(mesh, cams, outs, renderer=Renderer(W, H)))
    assert [v["index"] for v in two] == list(range(len(cams)))
    for a, b in zip(two, seq, strict=True):
        assert a["camera"] is b["camera"] is cams[a["index"]]
        for name in outs:
            np.testing.assert_array_equal(a[name], b[name], err_msg=f"{a['index']} {name}")


class Exploding:
    """A camera whose projection fails with an error that is not the view's fault."""

    def view_projection(self, width, height):
        raise RuntimeError("boom")


def test_broken_and_failing_views_land_at_their_place(mesh):
    cams: list = path_cameras(4)
    cams[2] = {"eye": [0, 1, 5], "target": [0, 0, 0], "near": 2.0, "far": 1.0}
    gen = Renderer(W, H).render_many(mesh, cams)
    next(gen), next(gen)
    with pytest.raises(ViewError, match=r"camera 2: field 'far'"):
        next(gen)
    assert not workers_alive()

    cams = path_cameras(4)
    cams[3] = Exploding()
    r = Renderer(W, H)
    expected = [one_at_a_time().render(mesh, c) for c in cams[:3]]
    got = []
    with pytest.raises(RuntimeError, match="boom"):
        for f in r.render_many(mesh, cams):
            got.append(f)
    assert len(got) == 3
    for k in range(3):
        assert_frames_equal(got[k], expected[k], f"view {k}")
    assert not workers_alive()
    # the renderer (and its partner) still render afterwards
    assert_frames_equal(next(r.render_many(mesh, cams[:1])), expected[0], "after")


def test_lazy_camera_list_failing_halfway(mesh):
    cams = path_cameras(4)

    def read():
        yield from cams[:3]
        raise OSError("camera source gone")

    got = []
    with pytest.raises(OSError, match="camera source gone"):
        for f in Renderer(W, H).render_many(mesh, read()):
            got.append(f)
    assert len(got) == 3
    assert not workers_alive()


def test_closing_early_stops_the_workers(mesh):
    r = Renderer(W, H)
    gen = r.render_many(mesh, path_cameras(12))
    first = next(gen)
    gen.close()
    assert not workers_alive()
    assert_frames_equal(first, one_at_a_time().render(mesh, path_cameras(12)[0]), "first")


def test_renders_fewer_views_than_two(mesh):
    cams = path_cameras(1)[:1]
    got = list(Renderer(W, H).render_many(mesh, cams))
    assert len(got) == 1
    assert list(Renderer(W, H).render_many(mesh, [])) == []
    assert not workers_alive()
