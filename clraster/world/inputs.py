"""What a caller renders: a clraster `Mesh` or `Scene`, or a trimesh ``Trimesh`` or ``Scene``.

`as_target` is the one place where it becomes a clraster Mesh or Scene. The public
entrances (`Renderer.render`, the twin's `render`, `render_many`, the batch jobs, shading and
the frame outputs) call it once; everything below them takes a Mesh or a Scene only.
"""

from __future__ import annotations

import sys
import threading
import weakref
from typing import TYPE_CHECKING, Any, Union

from .mesh import Mesh
from .scene import Scene

if TYPE_CHECKING:
    import trimesh

__all__ = ["Target", "as_target"]

#: What the renderers draw (`as_target` turns it into a Mesh or a Scene).
Target = Union[Mesh, Scene, "trimesh.Trimesh", "trimesh.Scene"]


#: trimesh object id → (weak reference to it, its content hash when converted, the
#: converted Mesh or Scene). Weak: the entry goes when the trimesh object does.
_CONVERTED: dict[int, tuple[weakref.ref, int, Any]] = {}
_CONVERTED_LOCK = threading.Lock()


def as_target(obj: object) -> Mesh | Scene:
    """What the renderers draw: ``obj`` itself if it is a `clraster.Mesh` or
    `clraster.Scene`; a ``trimesh.Trimesh`` as a Mesh (`Mesh.from_trimesh`: same vertices
    and faces, in order, so ids are its face indices); a ``trimesh.Scene`` as a Scene
    (`Scene.from_trimesh`: node transforms, node and geometry names kept; ids as the
    `clraster.scene` module docstring says, ``scene.geometry_of(ids)`` names them).

    A trimesh object is converted once and the result kept while the object lives (a weak
    reference) and its content is unchanged (trimesh's own content hash, cheap when nothing
    changed): repeated frames of one trimesh object reuse one clraster object, so the
    renderers' per-scene caches (clusters, BVH, uploaded geometry) hold; a changed object
    is converted again. ``as_target(tm_scene)`` returns that same Scene, the one to map a
    frame's ids back with.

    Raises:
        ValueError: another type (the message says what is accepted), a trimesh mesh with
            no face (a point cloud loaded as a mesh: rendering it would give a blank
            image), or a trimesh scene with no triangle mesh.
    """
    if isinstance(obj, (Mesh, Scene)):
        return obj
    kind = _trimesh_kind(obj)
    if kind is None:
        raise ValueError(f"expected a clraster.Mesh or clraster.Scene (or a trimesh.Trimesh "
                         f"or trimesh.Scene), got {type(obj).__name__}")
    key = id(obj)
    stamp = hash(obj)   # trimesh: a content hash, recomputed only after a change
    with _CONVERTED_LOCK:
        entry = _CONVERTED.get(key)
        if entry is not None and entry[0]() is obj and entry[1] == stamp:
            return entry[2]
    tm: Any = obj
    target: Mesh | Scene
    if kind == "mesh":
        if len(tm.faces) == 0:
            raise ValueError(f"the trimesh.Trimesh has no faces ({len(tm.vertices):,} "
                             f"vertices): a point cloud or lines? clraster renders triangle "
                             f"meshes")
        target = Mesh.from_trimesh(tm)
    else:
        target = Scene.from_trimesh(tm)

    def forget(ref: weakref.ref, key: int = key) -> None:
        with _CONVERTED_LOCK:
            if key in _CONVERTED and _CONVERTED[key][0] is ref:
                del _CONVERTED[key]

    with _CONVERTED_LOCK:
        _CONVERTED[key] = (weakref.ref(obj, forget), stamp, target)
    return target


def _trimesh_kind(obj: object) -> str | None:
    """"mesh" for a trimesh.Trimesh, "scene" for a trimesh.Scene, else None (without
    importing trimesh: if it is not imported, ``obj`` cannot be one of its objects)."""
    trimesh = sys.modules.get("trimesh")
    if trimesh is None:
        return None

    if isinstance(obj, trimesh.Trimesh):
        return "mesh"
    if isinstance(obj, trimesh.Scene):
        return "scene"
    return None
