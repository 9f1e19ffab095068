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

The package is grouped by layer, each importing only the layers below it: `clraster.base`
(config, kernel layout, input checks), `clraster.world` (meshes, scenes, cameras),
`clraster.clip` (2-D polygons, windows), `clraster.culling`, `clraster.output` (frames,
files, shading), `clraster.pipeline` (the frame driver, the OpenCL renderer and its NumPy
twin), `clraster.scale` (many views, Dask); the command lines sit on top. The public
modules keep their short names (``clraster.views`` is ``clraster.world.views``:
`clraster._aliases`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from . import _aliases
from .base.config import RasterConfig
from .world.camera import Camera
from .world.mesh import Mesh

if TYPE_CHECKING:
    from .culling.fates import ClusterFates
    from .output.frame import Frame, FrameStats
    from .pipeline import reference
    from .pipeline.boxes import Occlusion
    from .pipeline.lines import LineRenderer, render_lines
    from .pipeline.renderer import Renderer
    from .pipeline.segments import LineFrame
    from .viewer.command import view
    from .world.scene import Instance, Scene, SceneWarning

__all__ = ["Camera", "ClusterFates", "Frame", "FrameStats", "Instance", "LineFrame",
           "LineRenderer", "Mesh", "Occlusion", "RasterConfig", "Renderer", "Scene",
           "SceneWarning", "reference", "render_lines", "view"]
__version__ = "0.1.0"

_aliases.install()   # the public modules' short names (clraster.views, clraster.shade, ...)

_LAZY: dict[str, tuple[str, str | None]] = {
    "Renderer": ("clraster.pipeline.renderer", "Renderer"),
    "Frame": ("clraster.output.frame", "Frame"),
    "FrameStats": ("clraster.output.frame", "FrameStats"),
    "LineRenderer": ("clraster.pipeline.lines", "LineRenderer"),
    "LineFrame": ("clraster.pipeline.segments", "LineFrame"),
    "render_lines": ("clraster.pipeline.lines", "render_lines"),
    "Scene": ("clraster.world.scene", "Scene"),
    "Instance": ("clraster.world.scene", "Instance"),
    "SceneWarning": ("clraster.world.scene", "SceneWarning"),
    "ClusterFates": ("clraster.culling.fates", "ClusterFates"),
    "Occlusion": ("clraster.pipeline.boxes", "Occlusion"),
    "view": ("clraster.viewer.command", "view"),
}
# public submodules by their short names, importable as attributes
# (``clraster.shade.shade(frame, mesh)``, ``clraster.reference.render(...)``)
_LAZY.update((old.rpartition(".")[2], (old, None)) for old in _aliases.OLD_PATHS)


def __getattr__(name: str) -> Any:
    # PEP 562: load the OpenCL side only when it is asked for.
    if name in _LAZY:
        module_name, attr = _LAZY[name]
        module = importlib.import_module(module_name)
        value = module if attr is None else getattr(module, attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'clraster' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
