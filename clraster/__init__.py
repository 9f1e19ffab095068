"""clraster: a tile-based software rasterizer on CPU OpenCL (PoCL), with an exact NumPy twin.

Quick start::

    import clraster
    mesh = clraster.Mesh.load("bunny.ply")
    cam = clraster.Camera.look_at(eye=(0, 0, 3), target=(0, 0, 0), up=(0, 1, 0))
    frame = clraster.Renderer(1280, 720).render(mesh, cam)        # OpenCL
    same = clraster.reference.render(mesh, cam, 1280, 720)        # NumPy reference

Line segments (frustums, wireframes): ``clraster.LineRenderer`` / ``clraster.render_lines``
(Cohen–Sutherland clipping in clip space, depth-tested; see `clraster.lines`).

Scenes of many instances: ``clraster.Scene`` (``Scene.load(path)``,
``Scene.from_trimesh(tm_scene)``); the renderers also take a ``trimesh.Trimesh`` or
``trimesh.Scene`` directly (`clraster.inputs.as_target`).

``Renderer``, ``reference``, ``Frame``, ``FrameStats``, ``Scene`` and the line API are
imported on first use, and so are the public submodules (``clraster.shade``,
``clraster.views``, ``clraster.batch``, ...: ``clraster.shade.shade`` works without an
``import clraster.shade`` first), so
``import clraster`` (and ``Mesh``, ``Camera``, ``RasterConfig``) works without touching
OpenCL.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .camera import Camera
from .config import RasterConfig
from .mesh import Mesh

if TYPE_CHECKING:
    from . import reference
    from .boxes import Occlusion
    from .fates import ClusterFates
    from .frame import Frame, FrameStats
    from .lines import LineFrame, LineRenderer, render_lines
    from .renderer import Renderer
    from .scene import Instance, Scene, SceneWarning

__all__ = ["Camera", "ClusterFates", "Frame", "FrameStats", "Instance", "LineFrame",
           "LineRenderer", "Mesh", "Occlusion", "RasterConfig", "Renderer", "Scene",
           "SceneWarning", "reference", "render_lines"]
__version__ = "0.1.0"

_LAZY: dict[str, tuple[str, str | None]] = {
    "Renderer": (".renderer", "Renderer"),
    "reference": (".reference", None),
    "Frame": (".frame", "Frame"),
    "FrameStats": (".frame", "FrameStats"),
    "LineRenderer": (".lines", "LineRenderer"),
    "LineFrame": (".lines", "LineFrame"),
    "render_lines": (".lines", "render_lines"),
    "Scene": (".scene", "Scene"),
    "Instance": (".scene", "Instance"),
    "SceneWarning": (".scene", "SceneWarning"),
    "ClusterFates": (".fates", "ClusterFates"),
    "Occlusion": (".boxes", "Occlusion"),
}
# public submodules, importable as attributes (``clraster.shade.shade(frame, mesh)``)
_LAZY.update((name, ("." + name, None)) for name in (
    "batch", "composite", "distributed", "fates", "inputs", "lines", "occlusion", "scene",
    "scenes", "shade", "views"))


def __getattr__(name: str) -> Any:
    # PEP 562: load the OpenCL side only when it is asked for.
    if name in _LAZY:
        module_name, attr = _LAZY[name]
        module = importlib.import_module(module_name, __name__)
        value = module if attr is None else getattr(module, attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'clraster' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
