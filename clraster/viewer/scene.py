"""What the viewer shows: the target named on the command line, its starting camera and the
fly-through camera model.

Targets (`load_target`): ``plant`` (the procedural power plant of 1M triangles,
`clraster.scenes.plant`) or ``plant:N`` (N triangles, ``plant:10M`` and ``plant:2.5e6``
allowed), ``example`` (the built-in example scene), a path to a mesh or scene file
trimesh reads (`clraster.Scene.load`), or a `clraster.Mesh` / `clraster.Scene` / trimesh
object from Python.

Camera (`FlyCamera`): an eye and a heading — yaw about the world's +y axis (0 looks
along +x, 90° along +z) and pitch above the horizon (±`MAX_PITCH`); up is +y. It becomes
``Camera.look_at(eye, eye + direction, (0, 1, 0), fov_y, near, far)``, the look-at entry
``clraster render --views`` reads (`FlyCamera.entry`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..world.camera import Camera
from ..world.scene import Scene

__all__ = ["MAX_PITCH", "MAX_PLANT_TRIANGLES", "FlyCamera", "TargetError", "ViewerScene",
           "load_target"]

#: Largest |pitch| in degrees: the view direction never becomes parallel to up.
MAX_PITCH = 89.0
#: Largest ``plant:N``: host memory (~300 bytes per triangle, `clraster.demo`'s measure)
#: stays under ~15 GiB.
MAX_PLANT_TRIANGLES = 50_000_000
_MIN_PLANT_TRIANGLES = 2_000
_PLANT_DEFAULT = 1_000_000


class TargetError(ValueError):
    """A viewer target that cannot be loaded: the message says what was wrong and what to
    give instead."""


@dataclass(frozen=True)
class FlyCamera:
    """A fly-through camera: `eye` (world, float64 (3,)), `yaw` and `pitch` in degrees, and
    the lens (`fov_y` degrees, `near` and `far` distances)."""

    eye: tuple[float, float, float]
    yaw: float
    pitch: float
    fov_y: float
    near: float
    far: float

    @property
    def direction(self) -> np.ndarray:
        """Unit view direction, float64 (3,)."""
        y, p = math.radians(self.yaw), math.radians(self.pitch)
        return np.array([math.cos(p) * math.cos(y), math.sin(p), math.cos(p) * math.sin(y)])

    def camera(self) -> Camera:
        """The `clraster.Camera` this fly camera is (exactly `entry`'s look-at camera)."""
        e = self.entry()
        return Camera.look_at(e["eye"], e["target"], e["up"], fov_y=self.fov_y,
                              near=self.near, far=self.far)

    def entry(self) -> dict[str, Any]:
        """The camera as a look-at entry of a camera list file (`clraster.views`); the
        numbers are float64 and survive JSON exactly."""
        eye = np.asarray(self.eye, np.float64)
        target = eye + self.direction
        return {"eye": eye.tolist(), "target": target.tolist(), "up": [0.0, 1.0, 0.0],
                "fov_y": self.fov_y, "near": self.near, "far": self.far}

    def moved(self, eye: Any, yaw: float, pitch: float) -> FlyCamera:
        """The same lens at a new `eye`, `yaw` and `pitch` (pitch clamped to ±MAX_PITCH,
        yaw wrapped to [0, 360))."""
        e = tuple(float(v) for v in eye)
        return FlyCamera((e[0], e[1], e[2]), float(yaw) % 360.0,
                         float(min(max(pitch, -MAX_PITCH), MAX_PITCH)), self.fov_y,
                         self.near, self.far)

    @classmethod
    def from_camera(cls, cam: Camera, near: float, far: float) -> FlyCamera:
        """The fly camera at `cam`'s eye looking its way (its roll is dropped)."""
        d = -np.asarray(cam.view, np.float64)[2, :3]
        d /= np.linalg.norm(d)
        yaw = math.degrees(math.atan2(d[2], d[0]))
        pitch = math.degrees(math.asin(max(-1.0, min(1.0, d[1]))))
        eye = tuple(float(v) for v in cam.eye)
        return cls((eye[0], eye[1], eye[2]), 0.0, 0.0, float(cam.fov_y or 60.0), near,
                   far).moved(eye, yaw, pitch)


@dataclass
class ViewerScene:
    """A loaded target: the `clraster.Scene`, its name, bounds (float64 (3,) each), the
    starting camera, the walking speed (scene units per second), and whether it is a
    `clraster.scenes.plant` building (then the third-person view cuts away the storeys
    above the eye's)."""

    name: str
    scene: Scene
    lo: np.ndarray
    hi: np.ndarray
    start: FlyCamera
    speed: float
    plant: bool

    @property
    def diagonal(self) -> float:
        return float(np.linalg.norm(self.hi - self.lo))


def _plant_count(text: str) -> int:
    spec = text.strip().lower().replace("_", "").replace(",", "")
    scale = 1
    if spec[-1:] in ("k", "m"):
        scale = 1000 if spec[-1] == "k" else 1_000_000
        spec = spec[:-1]
    try:
        value = float(spec) * scale
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value == int(value)
            and _MIN_PLANT_TRIANGLES <= value <= MAX_PLANT_TRIANGLES):
        raise TargetError(f"plant:N needs a whole number of triangles from "
                          f"{_MIN_PLANT_TRIANGLES:,} to {MAX_PLANT_TRIANGLES:,} (e.g. "
                          f"plant:10M), got {text!r}")
    return int(value)


def load_target(target: Any, width: int, height: int) -> ViewerScene:
    """Load what ``clraster view TARGET`` names (see the module docstring) for a
    ``width × height`` view. Raises `TargetError` (a ValueError) for a name that is none
    of them or a file that cannot be read."""
    from ..world.inputs import as_target

    plant = False
    if isinstance(target, str) and (target == "plant" or target.startswith("plant:")):
        from ..world.generators import plant as make_plant
        from ..world.generators import plant_inside_camera

        n = _PLANT_DEFAULT if target == "plant" else _plant_count(target[6:])
        scene = make_plant(n)
        name, plant = f"plant({n:,})", True
        start_cam = plant_inside_camera(scene, width, height)
    else:
        if isinstance(target, str) and target == "example":
            from ..world.examples import example_mesh

            obj: Any = example_mesh()
            name = "example"
        elif isinstance(target, (str, Path)):
            path = Path(target)
            if not path.is_file():
                raise TargetError(f"TARGET {str(target)!r} is neither a file nor one of "
                                  f"'plant', 'plant:N', 'example'; give a mesh or scene "
                                  f"file trimesh reads (PLY, OBJ, STL, glTF, ...)")
            obj = Scene.load(path)
            name = path.name
        else:
            obj = target
            name = type(target).__name__
        converted = as_target(obj)
        scene = converted if isinstance(converted, Scene) else Scene.from_mesh(converted)
        if scene.n_faces == 0:
            raise TargetError(f"TARGET {name!r} has no triangles to show")
        lo, hi = (np.asarray(a, np.float64) for a in scene.bounds())
        start_cam = Camera.framing(lo, hi, direction=(1.0, 0.6, 1.6), fov_y=50.0,
                                   aspect=width / height)
    lo, hi = (np.asarray(a, np.float64) for a in scene.bounds())
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    if plant:
        near, far, speed = 0.1, diag, 3.0   # metres; walking pace
    else:
        dist = float(np.linalg.norm(np.asarray(start_cam.eye) - (lo + hi) / 2))
        near, far, speed = diag * 1e-3, dist + 2.0 * diag, diag / 8.0
    start = FlyCamera.from_camera(start_cam, near, far)
    return ViewerScene(name, scene, lo, hi, start, speed, plant)

