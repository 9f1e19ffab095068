"""The built-in example scene: deterministic, sized as documented, wound outward."""

from __future__ import annotations

import numpy as np

from clraster.world.examples import _example_parts, example_mesh, torus_knot


def test_deterministic_and_sized():
    a, b = example_mesh(), example_mesh()
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert 20_000 <= a.n_faces <= 100_000
    lo, hi = a.bounds()
    np.testing.assert_allclose(lo, [-4, 0, -4], atol=1e-6)
    assert hi[1] < 3.0 and np.allclose(hi[[0, 2]], 4)
    assert np.isfinite(a.vertices).all()


def test_ground_faces_up_and_objects_wound_outward():
    m = example_mesh()
    ground = 2 * 64 * 64
    np.testing.assert_allclose(m.face_normals()[:ground], [[0, 1, 0]] * ground, atol=1e-6)
    parts = _example_parts()
    assert sum(len(p.faces) for p in parts) == m.n_faces
    for part in parts[1:]:
        # Closed, consistently wound, positive signed volume: counter-clockwise from outside.
        assert part.is_watertight and part.is_winding_consistent
        assert part.volume > 0


def test_torus_knot_closed_outward():
    k = torus_knot(segments=64, sides=8)
    assert len(k.faces) == 2 * 64 * 8
    assert k.is_watertight and k.is_winding_consistent and k.volume > 0
