"""Two views in flight (`RasterConfig.views_in_flight`, `Renderer.view_partner`): the many-view
paths draw every other view with a second renderer in a thread of its own. The frames must be
exactly the one-at-a-time ones, in camera order; failures land at their own view; closing
early or failing leaves no worker behind."""

from __future__ import annotations

import threading

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
    # both renderers drew views (whichever is free takes the next camera); the first
    # view is drawn alone, by the renderer asked
    makers = [f.source() for f in got]
    assert makers[0] is r and r._partner is not None and r._partner in makers
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
