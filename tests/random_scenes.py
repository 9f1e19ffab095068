"""Random triangle soups for the differential tests (OpenCL vs the NumPy twin).

Triangles are drawn in eye space (camera at the origin looking down −Z) and seen through a
gluPerspective projection, so each kind lands where it is meant to: on screen, as slivers,
sub-pixel specks, huge triangles that leave the guard band, triangles crossing the near or
far plane, with vertices at w = 0 or behind the eye, fully behind the eye, degenerate
(collinear or repeated vertices), exact duplicates of earlier triangles (depth ties), and a
connected grid strip crossing the near plane (shared edges through the clipper).

Used by test_differential.py and, in a subprocess, by test_oclgrind.py; depends on NumPy
only (plus clraster.Mesh).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

KINDS = ("small", "tiny", "sliver", "medium", "huge", "near", "far", "behind", "degenerate",
         "offscreen", "duplicate", "grid")
#: Relative frequencies. Huge and near-crossing triangles cover most of the image, which is
#: what the twin pays for (per fragment), so they are kept rare but always present.
WEIGHTS = np.array([30, 10, 10, 8, 0.6, 5, 3, 3, 5, 4, 4, 6], dtype=np.float64)


@dataclass
class Lens:
    fov_y: float
    near: float
    far: float

    def projection(self, aspect: float) -> np.ndarray:
        f = 1.0 / math.tan(math.radians(self.fov_y) / 2.0)
        p = np.zeros((4, 4))
        p[0, 0] = f / aspect
        p[1, 1] = f
        p[2, 2] = (self.far + self.near) / (self.near - self.far)
        p[2, 3] = 2.0 * self.far * self.near / (self.near - self.far)
        p[3, 2] = -1.0
        return p


def _eye_point(px, py, d, width, height, lens: Lens):
    """Eye-space point seen at window position (px, py) (pixels, y down) at distance d."""
    ty = math.tan(math.radians(lens.fov_y) / 2.0)
    tx = ty * width / height
    xn = np.asarray(px) / width * 2.0 - 1.0
    yn = 1.0 - np.asarray(py) / height * 2.0
    d = np.asarray(d, dtype=np.float64)
    return np.stack([xn * tx * d, yn * ty * d, -d], axis=-1)


def random_soup(rng: np.random.Generator, n: int, width: int, height: int, lens: Lens
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` random triangles in eye space.

    Returns:
        vertices float64 (V, 3), faces int64 (n, 3), kind index per face int (n,)
        (an index into KINDS).
    """
    kinds = rng.choice(len(KINDS), size=n, p=WEIGHTS / WEIGHTS.sum())
    near, far = lens.near, lens.far
    verts: list[np.ndarray] = []
    faces = np.zeros((n, 3), np.int64)
    nv = 0

    def add(tri: np.ndarray) -> np.ndarray:
        nonlocal nv
        verts.append(np.asarray(tri, dtype=np.float64).reshape(-1, 3))
        idx = np.arange(nv, nv + verts[-1].shape[0])
        nv += verts[-1].shape[0]
        return idx

    def depth():  # log-uniform in [near, far]
        return math.exp(rng.uniform(math.log(near), math.log(far)))

    def screen_tri(scale_px: float, margin: float = 0.05) -> np.ndarray:
        cx = rng.uniform(-margin * width, (1 + margin) * width)
        cy = rng.uniform(-margin * height, (1 + margin) * height)
        d = depth()
        off = rng.normal(0.0, scale_px, (3, 2))
        dd = d * (1.0 + rng.normal(0.0, 0.05, 3))
        dd = np.clip(dd, near * 1.0001, far * 0.9999)
        return _eye_point(cx + off[:, 0], cy + off[:, 1], dd, width, height, lens)

    grid_left = 0
    t = 0
    while t < n:
        k = KINDS[kinds[t]]
        if k == "small":
            tri = screen_tri(math.exp(rng.uniform(math.log(0.8), math.log(6.0))))
        elif k == "tiny":
            tri = screen_tri(rng.uniform(0.02, 0.5))
        elif k == "medium":
            tri = screen_tri(rng.uniform(6.0, 20.0))
        elif k == "sliver":
            a = rng.uniform([-5, -5], [width + 5, height + 5])
            ang = rng.uniform(0, 2 * math.pi)
            length = rng.uniform(5, 2 * max(width, height))
            u = np.array([math.cos(ang), math.sin(ang)])
            b = a + length * u
            c = a + rng.uniform(-0.5, 1.5) * (b - a) + np.array([-u[1], u[0]]) * (
                rng.choice([-1, 1]) * 10 ** rng.uniform(-3, 0))
            p = np.stack([a, b, c])
            tri = _eye_point(p[:, 0], p[:, 1], np.full(3, depth()), width, height, lens)
        elif k == "huge":
            # NDC coordinates up to ±1e6: beyond the guard band (2**19 px) for some.
            mag = 10 ** rng.uniform(0.5, 6.0, (3, 1))
            dirs = rng.normal(size=(3, 2))
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            p = dirs * mag
            d = rng.uniform(near, far, 3)
            px = (p[:, 0] + 1) * 0.5 * width
            py = (1 - p[:, 1]) * 0.5 * height
            tri = _eye_point(px, py, d, width, height, lens)
        elif k == "near":
            # straddles z = −near; some vertices at w = 0 exactly or behind the eye
            tri = np.empty((3, 3))
            tri[:, :2] = rng.uniform(-3 * near, 3 * near, (3, 2))
            tri[:, 2] = rng.uniform(-4 * near, 1.5 * near, 3)
            special = rng.random(3)
            tri[special < 0.15, 2] = 0.0  # w = 0
            tri[(special >= 0.15) & (special < 0.25), 2] = -near  # exactly on the near plane
            if np.all(tri[:, 2] > -near):
                tri[0, 2] = -near * rng.uniform(1.01, 4)
            if np.all(tri[:, 2] <= -near):
                tri[1, 2] = rng.uniform(-near * 0.99, near)
        elif k == "far":
            tri = screen_tri(rng.uniform(2, 15))
            tri[:, 2] = -rng.uniform(far * 0.7, far * 1.4, 3)
            tri[0, 2] = -far * rng.uniform(0.5, 0.99)
            tri[1, 2] = -far * rng.uniform(1.01, 1.5)
        elif k == "behind":
            tri = rng.uniform(-2 * near, 2 * near, (3, 3))
            tri[:, 2] = rng.uniform(0.0, 3 * near, 3)
        elif k == "degenerate":
            base = screen_tri(rng.uniform(1, 10))
            r = rng.random()
            if r < 0.4:  # collinear in eye space: collinear in clip and window space too
                base[2] = base[0] + rng.uniform(-1, 2) * (base[1] - base[0])
            elif r < 0.7:  # two coincident vertices
                base[1] = base[0]
            else:  # all three the same point
                base[:] = base[0]
            tri = base
        elif k == "offscreen":
            tri = screen_tri(rng.uniform(1, 8), margin=0.0)
            side = rng.integers(4)
            shift = np.array([[2.0, 0.0], [-2.0, 0.0], [0.0, 2.0], [0.0, -2.0]])[side]
            # push every vertex past one side: x_ndc or y_ndc beyond ±1
            d = -tri[:, 2]
            ty = math.tan(math.radians(lens.fov_y) / 2.0)
            tx = ty * width / height
            tri[:, 0] += shift[0] * tx * d * rng.uniform(1.0, 3.0)
            tri[:, 1] += shift[1] * ty * d * rng.uniform(1.0, 3.0)
        elif k == "duplicate" and t > 0:
            src = faces[rng.integers(t)]
            faces[t] = src if rng.random() < 0.5 else src[[0, 2, 1]]
            t += 1
            continue
        elif k == "grid" or k == "duplicate":
            if grid_left == 0:
                # an (g+1)² vertex grid on a tilted plane through the near plane; its quads
                # split along a diagonal become the next faces (shared edges, shared
                # vertices: the clipper must not open cracks between them)
                g = int(rng.integers(2, 5))
                lin = np.linspace(-1, 1, g + 1)
                u, v = np.meshgrid(lin, lin)
                size = near * rng.uniform(1, 6)
                z = -near * rng.uniform(0.5, 3) + size * (rng.uniform(-1, 1) * u
                                                         + rng.uniform(-1, 1) * v)
                gv = np.stack([u * size, v * size, z], axis=-1).reshape(-1, 3)
                gv[:, :2] += rng.uniform(-near, near, 2)
                g0 = add(gv)[0]
                quads = []
                for j in range(g):
                    for i in range(g):
                        a = g0 + j * (g + 1) + i
                        quads += [[a, a + 1, a + g + 2], [a, a + g + 2, a + g + 1]]
                grid_faces = np.array(quads)
                if rng.random() < 0.5:
                    grid_faces = grid_faces[:, [0, 2, 1]]
                grid_left = len(grid_faces)
            faces[t] = grid_faces[len(grid_faces) - grid_left]
            grid_left -= 1
            t += 1
            continue
        else:  # pragma: no cover
            raise AssertionError(k)
        perm = rng.permutation(3)  # random winding
        faces[t] = add(np.asarray(tri)[perm])
        t += 1
    vertices = np.concatenate(verts) if verts else np.zeros((0, 3))
    return vertices, faces, kinds


def random_view(rng: np.random.Generator) -> np.ndarray:
    """A random rigid world → eye matrix (rotation and translation)."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    a, b, c, d = q
    rot = np.array([
        [a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
        [2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)],
        [2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d]])
    view = np.eye(4)
    view[:3, :3] = rot
    view[:3, 3] = rng.uniform(-5, 5, 3)
    return view


def to_world(eye_vertices: np.ndarray, view: np.ndarray) -> np.ndarray:
    """Eye-space points → world space for the given view matrix."""
    inv = np.linalg.inv(view)
    h = np.concatenate([eye_vertices, np.ones((eye_vertices.shape[0], 1))], axis=1)
    with np.errstate(invalid="ignore", over="ignore"):  # NaN/Inf vertices stay non-finite
        return (h @ inv.T)[:, :3]
