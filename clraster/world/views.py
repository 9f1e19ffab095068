"""Many views of one scene: camera lists (Python or a JSON file), and `frames`, the loop that
renders a target from each (the engine of `Renderer.render_many` and `clraster.batch`).

Camera list file (JSON, UTF-8): either a bare list of entries or an object
``{"cameras": [entry, ...]}``. Each entry is one of two kinds:

* look-at (gluLookAt + gluPerspective, as `clraster.Camera.look_at`)::

      {"eye": [x, y, z], "target": [x, y, z], "up": [0, 1, 0],
       "fov_y": 45.0, "near": 0.1, "far": 100.0}

  ``eye`` and ``target`` are required; ``up`` (default [0, 1, 0]), ``fov_y`` (vertical field
  of view in degrees, default 45), ``near`` (default 0.1) and ``far`` (default 100) are
  optional. The aspect ratio is the rendered image's width / height.
* matrices (as `clraster.Camera.from_matrices`)::

      {"view": [[...], [...], [...], [...]], "projection": [[...], ...]}

  4×4 each, row by row (``view[i][j]`` is row i, column j), for column vectors:
  ``clip = projection @ view @ [x, y, z, 1]``; the projection is used as it is whatever the
  image size, so it carries its own aspect ratio.

* intrinsics (as `clraster.Camera.from_intrinsics`)::

      {"K": [[fx, s, cx], [0, fy, cy], [0, 0, 1]], "pose": [[...], ...],
       "convention": "opencv", "near": 0.1, "far": 100.0, "width": 640, "height": 480}

  ``K`` in pixels with OpenCV's pixel centres (pixel (i, j)'s centre at (u, v) = (i, j));
  ``pose`` the 4×4 camera → world matrix (default identity) in ``convention``'s camera
  axes (``"opencv"``, the default: +y down, +z forward; ``"opengl"``: +y up, looking down
  −z); ``near`` and ``far`` are required (no default suits a metric scene); ``width`` and
  ``height`` (both or neither) are the image K belongs to, default the size rendered at.

An optional ``"name"`` (a string) is allowed in any kind and ignored by the renderer.

`load_cameras` also reads the camera files of other tools (`clraster.world.camera_files`): a
COLMAP text model (a folder), a NeRF / instant-ngp ``transforms.json`` (a JSON object with
``"frames"``) and an ``.npz`` with ``K`` and ``poses``.
Any other key is an error (a misspelt ``"fovy"`` must not silently become the default).
Python's JSON reader accepts ``NaN`` and ``Infinity``; such values are reported as broken.

A broken entry is reported by its index and field (`ViewError`: ``camera 3: field 'near':
near must be > 0 ...``). `load_cameras` raises on the first one by default; with
``strict=False`` it keeps a `BrokenCamera` in that place, which `clraster.batch.render_views`
turns into one failed view while the rest of the batch goes on.

Python camera lists may hold `clraster.Camera` objects, dicts in the file's entry format, or
any object with ``view_projection(width, height)`` (as `Renderer.render` accepts).
"""

from __future__ import annotations

import atexit
import contextvars
import json
import math
import os
import threading
import weakref
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

import numpy as np

from .camera import CONVENTIONS, Camera, projection_fault
from .camera_files import CameraFileError, nerf_cameras, read_colmap, read_npz
from .inputs import as_target

__all__ = ["BrokenCamera", "CameraFileError", "ViewError", "ViewRenderer", "camera_from_entry",
           "frames", "iter_cameras", "load_cameras"]

F = TypeVar("F", covariant=True)

_LOOK_AT_KEYS = ("eye", "target", "up", "fov_y", "near", "far")
_MATRIX_KEYS = ("view", "projection")
_INTRINSICS_KEYS = ("K", "pose", "convention", "near", "far", "width", "height")
_LOOK_AT_DEFAULTS: dict[str, Any] = {"up": (0.0, 1.0, 0.0), "fov_y": 45.0, "near": 0.1,
                                     "far": 100.0}


class ViewRenderer(Protocol[F]):
    """What `frames` renders with: a `clraster.Renderer` (frames of type F = `Frame`), or any
    object with an image size and a ``render(target, camera, **render_kwargs)``."""

    @property
    def width(self) -> int: ...

    @property
    def height(self) -> int: ...

    def render(self, *args: Any, **kwargs: Any) -> F: ...


class ViewError(ValueError):
    """One view cannot be rendered: ``index`` is its place in the camera list, ``field`` the
    entry's field at fault (None when it is not one field's fault)."""

    def __init__(self, index: int, field: str | None, message: str) -> None:
        self.index = index
        self.field = field
        self.message = message
        where = f"camera {index}" + (f": field {field!r}" if field else "")
        super().__init__(f"{where}: {message}")

    def __reduce__(self):
        # pickle by the three fields: the default would call __init__ with the formatted
        # message alone, and a BrokenCamera in a camera list travels to Dask workers
        return (type(self), (self.index, self.field, self.message))


@dataclass(frozen=True)
class BrokenCamera:
    """Placeholder for a camera list entry that could not be made into a camera."""

    error: ViewError

    @property
    def index(self) -> int:
        return self.error.index


def _number(entry: dict, key: str, index: int) -> float:
    v = entry[key]
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise ViewError(index, key, f"must be a number, got {v!r}")
    f = float(v)
    if not math.isfinite(f):
        raise ViewError(index, key, f"must be finite, got {f}")
    return f


def _array(entry: dict, key: str, index: int, shape: tuple[int, ...]) -> np.ndarray:
    v = entry[key]
    what = ("3 numbers [x, y, z]" if shape == (3,) else
            f"a {shape[0]}x{shape[1]} matrix ({shape[0]} rows of {shape[1]} numbers)")
    try:
        a = np.asarray(v)
    except (TypeError, ValueError):   # ragged nested lists
        raise ViewError(index, key, f"must be {what}, got {v!r}") from None
    if a.dtype.kind not in "iuf" or a.shape != shape:
        raise ViewError(index, key, f"must be {what}, got {v!r}")
    a = a.astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise ViewError(index, key, f"must be finite, got {a.tolist()}")
    return a


def camera_from_entry(entry: Any, index: int, size: tuple[int, int] | None = None) -> Camera:
    """A `Camera` from one camera-list entry (the module docstring's format); ``size``
    (width, height): the image size rendered at, for intrinsics entries without their own.

    Raises:
        ViewError: naming ``index`` and the field at fault.
    """
    if not isinstance(entry, dict):
        raise ViewError(index, None, f"expected an object with 'eye'/'target' (look-at) or "
                                     f"'view'/'projection' (matrices), got "
                                     f"{type(entry).__name__} {entry!r:.60}")
    keys = set(entry) - {"name"}
    unknown = sorted(str(k) for k in keys - set(_LOOK_AT_KEYS) - set(_MATRIX_KEYS)
                     - set(_INTRINSICS_KEYS))
    if unknown:
        raise ViewError(index, unknown[0],
                        f"unknown field; a look-at entry has {', '.join(_LOOK_AT_KEYS)}, a "
                        f"matrices entry {', '.join(_MATRIX_KEYS)} and an intrinsics entry "
                        f"{', '.join(_INTRINSICS_KEYS)}")
    if "name" in entry and not isinstance(entry["name"], str):
        raise ViewError(index, "name", f"must be a string, got {entry['name']!r}")
    if "K" in keys:
        return _intrinsics_entry(entry, index, size)
    look, mats = keys & set(_LOOK_AT_KEYS), keys & set(_MATRIX_KEYS)
    if look and mats:
        raise ViewError(index, sorted(mats)[0],
                        f"an entry is either look-at ({', '.join(sorted(look))}) or matrices, "
                        f"not both")
    if mats:
        for key in _MATRIX_KEYS:
            if key not in entry:
                raise ViewError(index, key, "missing (a matrices entry needs both view and "
                                            "projection)")
        view = _array(entry, "view", index, (4, 4))
        proj = _array(entry, "projection", index, (4, 4))
        check_projection(proj, index)
        try:
            return Camera.from_matrices(view, proj)
        except ValueError as exc:
            raise ViewError(index, "view", str(exc)) from None
    for key in ("eye", "target"):
        if key not in entry:
            raise ViewError(index, key, "missing (a look-at entry needs eye and target; or "
                                        "give view and projection matrices)")
    e = {**_LOOK_AT_DEFAULTS, **entry}
    eye = _array(e, "eye", index, (3,))
    target = _array(e, "target", index, (3,))
    up = _array(e, "up", index, (3,))
    fov_y, near, far = (_number(e, k, index) for k in ("fov_y", "near", "far"))
    if not 0.0 < fov_y < 180.0:
        raise ViewError(index, "fov_y", f"is the vertical field of view in degrees and must "
                                        f"be in (0, 180), got {fov_y}")
    if near <= 0.0:
        raise ViewError(index, "near", f"must be > 0 (distance to the near plane), got {near}")
    if far <= near:
        raise ViewError(index, "far", f"must be > near, got near={near}, far={far}")
    if np.array_equal(eye, target):
        raise ViewError(index, "target", f"must differ from eye (both are {eye.tolist()})")
    try:
        return Camera.look_at(eye, target, up, fov_y=fov_y, near=near, far=far)
    except ValueError as exc:   # CameraArgumentError names the field: up zero or parallel
        # to the view direction, eye/target overflowing, a lens beyond float32
        raise ViewError(index, getattr(exc, "argument", "up"), str(exc)) from None


def _intrinsics_entry(entry: dict, index: int, size: tuple[int, int] | None) -> Camera:
    """An intrinsics entry (K, pose, convention, near, far, width, height)."""
    others = sorted((set(entry) - {"name"}) & (set(_LOOK_AT_KEYS) | set(_MATRIX_KEYS))
                    - set(_INTRINSICS_KEYS))
    if others:
        raise ViewError(index, others[0], "an intrinsics entry (K) takes K, pose, convention, "
                                          "near, far, width and height only")
    for key in ("near", "far"):
        if key not in entry:
            raise ViewError(index, key, "missing (an intrinsics entry needs near and far, "
                                        "in the scene's units)")
    k = _array(entry, "K", index, (3, 3))
    pose = _array(entry, "pose", index, (4, 4)) if "pose" in entry else None
    near, far = _number(entry, "near", index), _number(entry, "far", index)
    conv = entry.get("convention", "opencv")
    if conv not in CONVENTIONS:
        raise ViewError(index, "convention", f"must be one of {list(CONVENTIONS)}, got "
                                             f"{conv!r}")
    if ("width" in entry) != ("height" in entry):
        raise ViewError(index, "width" if "width" not in entry else "height",
                        "missing (give both width and height, or neither)")
    if "width" in entry:
        dims = []
        for key in ("width", "height"):
            v = entry[key]
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise ViewError(index, key, f"must be a positive integer, got {v!r}")
            dims.append(v)
        width, height = dims
    elif size is not None:
        width, height = size
    else:
        raise ViewError(index, "K", "an intrinsics entry without width and height needs the "
                                    "image size to render at")
    try:
        return Camera.from_intrinsics(k, width, height, pose=pose, near=near, far=far,
                                      convention=conv)
    except ValueError as exc:
        field = getattr(exc, "argument", None)
        raise ViewError(index, field if field in entry else "K", str(exc)) from None


def check_projection(proj: np.ndarray, index: int, field: str = "projection") -> None:
    """Refuse a projection (float64 (4, 4), finite) that cannot make an image: singular in
    float64 or float32, or beyond float32 (`clraster.camera.projection_fault`, which the
    camera constructors apply too), or a perspective one whose near plane is not in front of
    its far plane.

    For OpenGL's perspective (last row 0 0 −1 0) the planes are at the distances
    n = P23 / (P22 − 1) and f = P23 / (P22 + 1) (where NDC z is −1 and +1). Other
    projections are only checked for being invertible: an orthographic one with its planes
    swapped is a legitimate reversed depth range (the identity is one).
    """
    fault = projection_fault(proj)
    if fault is not None:
        raise ViewError(index, field, fault)
    if not np.array_equal(proj[3], (0.0, 0.0, -1.0, 0.0)):
        return
    n, f = proj[2, 3] / (proj[2, 2] - 1.0), proj[2, 3] / (proj[2, 2] + 1.0)
    if not 0.0 < n < f:
        raise ViewError(index, field, f"this perspective projection puts the near plane at "
                                      f"{n:.6g} and the far plane at {f:.6g}; it needs "
                                      f"0 < near < far")


def _check_camera(cam: Any, index: int, width: int, height: int) -> Any:
    """``cam`` if it can make a view-projection matrix for this image, else ViewError."""
    if isinstance(cam, Camera):
        if cam.image_size is not None and cam.image_size != (width, height):
            w, h = cam.image_size
            raise ViewError(index, None, f"the camera is for {w}x{h} images (its K is in their "
                                         f"pixels), not the {width}x{height} rendered")
        if cam.fov_y is None:   # from_matrices: its projection was never checked
            check_projection(np.asarray(cam.projection(width, height), np.float64), index)
        return cam
    if not callable(getattr(cam, "view_projection", None)):
        raise ViewError(index, None, f"expected a clraster.Camera or a camera entry (dict), "
                                     f"got {type(cam).__name__}")
    try:
        m = np.asarray(cam.view_projection(width, height), np.float64)
    except (TypeError, ValueError) as exc:
        raise ViewError(index, "view_projection", f"could not be computed: {exc}") from None
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ViewError(index, "view_projection", "must return a finite (4, 4) matrix")
    return cam


def iter_cameras(cameras: Iterable[Any] | str | os.PathLike, width: int, height: int
                 ) -> Iterator[tuple[int, Any]]:
    """(index, camera) for the entries of ``cameras`` in order, each checked for a
    ``width`` × ``height`` image: the camera object, or a `BrokenCamera` where the entry is
    broken (never raises for one entry). ``cameras``: a path to a camera list file
    (`load_cameras`), or an iterable of `Camera` objects, entry dicts, objects with
    ``view_projection`` or `BrokenCamera`s. Lazy: a generator is read one camera at a time."""
    if isinstance(cameras, (str, os.PathLike)):
        cameras = load_cameras(cameras, strict=False, size=(width, height))
    elif isinstance(cameras, (dict, Camera)):
        raise ValueError("cameras must be a list of cameras (or a camera list file), got one "
                         f"{type(cameras).__name__}; wrap it in a list")
    for index, entry in enumerate(cameras):
        if isinstance(entry, BrokenCamera):
            yield index, entry
            continue
        try:
            cam = (camera_from_entry(entry, index, (width, height)) if isinstance(entry, dict)
                   else entry)
            yield index, _check_camera(cam, index, width, height)
        except ViewError as exc:
            yield index, BrokenCamera(exc)


def load_cameras(path: str | os.PathLike, *, strict: bool = True,
                 size: tuple[int, int] | None = None, near: float | None = None,
                 far: float | None = None, drop_distortion: bool = False
                 ) -> list[Camera | BrokenCamera]:
    """Read a camera file: a camera list (JSON, the module docstring's format), a COLMAP
    text model (a folder with cameras.txt and images.txt, or sparse/0 below it), a NeRF /
    instant-ngp ``transforms.json`` (a JSON object with ``"frames"``) or an ``.npz`` with
    ``K`` and ``poses`` (`clraster.world.camera_files` has each format's conventions).

    Args:
        strict: raise `ViewError` (naming the entry's index and field) for the first broken
            entry of a camera list; False: keep a `BrokenCamera` in its place and go on.
            (The other formats are read whole or refused.)
        size: (width, height) rendered at: for intrinsics entries and files without a size
            of their own. Cameras of a file with a size are tied to it (`Camera.image_size`;
            `clraster.world.camera_files.common_size`).
        near, far: clip planes for the formats that carry none (COLMAP, NeRF, an .npz
            without them); refused for a camera list, whose entries carry their own.
        drop_distortion: render the pinhole part of a COLMAP / NeRF camera with lens
            distortion (else refused, naming the model).

    Raises:
        CameraFileError: the file is not UTF-8 JSON (nested too deeply for Python's
            reader counts as not JSON), or not a list of entries (nor an object with a
            ``"cameras"`` list, nor a transforms.json), or a COLMAP / NeRF / NPZ file that
            cannot be read; its message names the file. OSError: it cannot be read.
    """
    p = Path(path)
    width, height = size if size is not None else (None, None)
    if p.is_dir():
        return list(read_colmap(p, near=near, far=far, drop_distortion=drop_distortion)[0])
    if p.suffix.lower() == ".npz":
        if drop_distortion:
            raise CameraFileError(f"{p}: an .npz holds pinhole cameras; drop_distortion does "
                                  f"not apply")
        return list(read_npz(p, width=width, height=height, near=near, far=far))
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise CameraFileError(f"{p}: not a UTF-8 text file (byte {exc.start}: {exc.reason}); "
                              f"a camera list is JSON in UTF-8") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CameraFileError(f"{p}: not valid JSON: {exc.msg} at line {exc.lineno} column "
                              f"{exc.colno}") from None
    except RecursionError:   # Python's JSON reader recurses once per [ or {
        raise CameraFileError(f"{p}: JSON nested too deeply to read (a camera list needs 4 "
                              f"levels: list, entry, matrix, row)") from None
    except ValueError as exc:   # the rest of the reader's refusals, e.g. an integer of
        # more than 4300 digits (sys.set_int_max_str_digits)
        raise CameraFileError(f"{p}: not valid JSON: {exc}") from None
    if isinstance(doc, dict) and "frames" in doc:
        return list(nerf_cameras(doc, p, width=width, height=height, near=near, far=far,
                                 drop_distortion=drop_distortion)[0])
    given = [k for k, v in (("near", near), ("far", far), ("drop_distortion", drop_distortion))
             if v not in (None, False)]
    if given:
        raise CameraFileError(f"{p}: a camera list gives each entry's own clip planes and "
                              f"lens; {', '.join(given)} cannot be given for it")
    if isinstance(doc, dict):
        if set(doc) - {"cameras"} or not isinstance(doc.get("cameras"), list):
            raise CameraFileError(f"{p}: expected a list of camera entries or an object "
                                  f"{{\"cameras\": [...]}}, got an object with keys "
                                  f"{sorted(doc)}")
        doc = doc["cameras"]
    if not isinstance(doc, list):
        raise CameraFileError(f"{p}: expected a list of camera entries or an object "
                              f"{{\"cameras\": [...]}}, got {type(doc).__name__}")
    out: list[Camera | BrokenCamera] = []
    for index, entry in enumerate(doc):
        try:
            out.append(camera_from_entry(entry, index, size))
        except ViewError as exc:
            if strict:
                raise ViewError(exc.index, exc.field, f"{exc.message} (in {p})") from None
            out.append(BrokenCamera(exc))
    return out


def check_target(target: Any) -> None:
    """ValueError now, not once per view, unless ``target`` is a Mesh or a Scene (or a
    trimesh Trimesh or Scene, converted here once: `clraster.inputs.as_target` keeps the
    conversion for the views)."""
    as_target(target)


def cameras_in_hand(cameras: Any) -> bool:
    """Whether a camera source may be read ahead of the views, from other threads: a list
    or tuple, or a camera file (read into a list). Any other iterable is read one camera
    per view, in the caller's thread: it may wait on the caller's loop (the next camera
    chosen from the last frame), or belong to the thread that made it."""
    return isinstance(cameras, (list, tuple, str, os.PathLike))


def frames(renderer: ViewRenderer[F], target: Any,
           cameras: Iterable[Any] | str | os.PathLike, render_kwargs: dict,
           partner: ViewRenderer[F] | None = None) -> Iterator[tuple[int, F | ViewError]]:
    """(index, frame) per camera in order, or (index, `ViewError`) for a view that failed:
    a broken camera, or a camera `Renderer.render` refuses (ValueError: e.g. a matrix that
    overflows float32). Other exceptions propagate.

    Each view is one `Renderer.render` call. A plain loop of render calls on the same
    target already keeps the per-scene work — the Scene made from a Mesh, its clusters, BVH
    and geometry pool (`drawlist.PlanCache`), and the pool on the device
    (`GeometryStage.upload_pool` skips the same pool) — so what repeats per view is the
    view's own work: on the host culling and planning (~1.5 ms on the dragon), on the
    device the stages (~9 ms at 640 × 480), one after the other.

    ``partner``: a second renderer (`Renderer.view_partner`: same size, config and
    device; None: views one at a time), given only with a camera source in hand
    (`cameras_in_hand`; ``cameras`` may then be a generator over it). Two worker threads,
    one per renderer, each take the next camera (whichever is free) and render it, two
    views in flight, so that one view's host work and the caller's work on the last frame
    run while the device draws the other; the frames still come out in camera order, each
    exactly what ``renderer.render`` makes. The first view is drawn alone (what a first
    frame builds and caches is built once). Up to `_InFlight.AHEAD` views are read and
    rendered ahead of the caller. Closing the generator waits for the views being drawn
    and renders no more; an exception in the caller's wait (Ctrl-C) returns at once, the
    workers finishing their view in the background (and before the interpreter exits).
    """
    views = iter_cameras(cameras, renderer.width, renderer.height)
    if partner is None:
        for index, cam in views:
            yield index, _render_view(renderer, target, index, cam, render_kwargs)
        return
    yield from _InFlight((renderer, partner), target, views, render_kwargs).run()


#: `_InFlight` runs whose workers may still be alive, stopped and joined before the
#: interpreter exits (`_stop_all_runs`)
_LIVE_RUNS: weakref.WeakSet = weakref.WeakSet()


class _InFlight:
    """`frames` with two renderers: a worker thread per renderer takes the next camera
    (the list is read in order, under a lock), renders it and files the frame under its
    place in the list; the caller's generator hands them out in that order. The workers
    run ahead of the caller by at most `AHEAD` views in all (taken, not yet handed out),
    so a worker need not wait for the caller to come back before its next view (handing
    each view to a worker from the caller's thread gained a third of what this does:
    bench/README.md, "Views in flight"). Each worker runs in a copy of the caller's
    context (`contextvars`)."""

    AHEAD = 3

    def __init__(self, renderers: tuple[Any, Any], target: Any,
                 views: Iterator[tuple[int, Any]], render_kwargs: dict) -> None:
        self.renderers, self.target, self.views = renderers, target, views
        self.kwargs = render_kwargs
        self.lock = threading.Lock()   # guards views, taken, end, stop and done
        self.ready = threading.Condition(self.lock)
        self.taken = 0                 # views taken from the list so far
        self.end: int | None = None    # no view from here on: the list's end, or a failure
        self.stop = False
        # view n → (index, frame or ViewError), or (None, exception) to raise at n
        self.done: dict[int, tuple[int | None, Any]] = {}
        self.slots = threading.Semaphore(self.AHEAD)
        self.first = threading.Event()   # view 0 is drawn alone: what it caches, once
        self.workers: list[threading.Thread] = []

    def _take(self) -> tuple[int, int, Any] | None:
        """(n, index, camera) of the next view, or None: the list ended or failed (its
        error filed at the end), or the caller stopped. (The list is in hand, so reading
        it under the lock never waits on anyone.)"""
        with self.lock:
            if self.stop or self.end is not None:
                return None
            n = self.taken
            try:
                index, cam = next(self.views)
            except StopIteration:
                self.end = n
            except BaseException as exc:   # a broken entry's check failing otherwise: at n
                self.end = n + 1
                self.done[n] = (None, exc)
            else:
                self.taken = n + 1
                return n, index, cam
            self.ready.notify_all()
            return None

    def _work(self, renderer: Any) -> None:
        if renderer is not self.renderers[0]:
            self.first.wait()   # view 0 goes to the first renderer, alone
        while True:
            self.slots.acquire()
            got = None if self.stop else self._take()
            if got is None:
                return
            n, index, cam = got
            alone = False
            try:
                try:
                    out: tuple[int | None, Any] = (index, _render_view(
                        renderer, self.target, index, cam, self.kwargs))
                except Exception as exc:
                    if renderer is self.renderers[0] or not _out_of_memory(exc):
                        raise
                    # the second renderer could not allocate its buffers: this view and the
                    # rest go to the first one (its lock serializes the two), which lets go
                    # of it (`drop_view_partner`)
                    drop = getattr(self.renderers[0], "drop_view_partner", None)
                    if drop is not None:
                        drop()
                    alone = True
                    out = (index, _render_view(self.renderers[0], self.target, index, cam,
                                               self.kwargs))
            except BaseException as exc:   # raised in the caller, at view n
                out = (None, exc)
                with self.lock:   # no views after n are taken: the caller stops at n
                    self.end = n + 1 if self.end is None else min(self.end, n + 1)
            finally:
                self.first.set()
            with self.lock:
                self.done[n] = out
                self.ready.notify_all()
            if alone:
                return

    def _stop(self, join: bool) -> None:
        """No more views: wake the workers (waiting for a slot or for view 0); with
        ``join``, wait until each has finished the view it is drawing. In a worker's own
        thread (the generator collected there, maybe inside `_take`, under the lock),
        neither the lock nor a join."""
        mine = threading.current_thread() in self.workers
        if mine:
            self.stop = True
        else:
            with self.lock:
                self.stop = True
        for _ in self.workers:
            self.slots.release()
        self.first.set()
        if join and not mine:
            for t in self.workers:
                t.join()

    def run(self) -> Iterator[tuple[int, Any]]:
        interrupted = False
        try:
            _LIVE_RUNS.add(self)
            for r in self.renderers:
                ctx = contextvars.copy_context()
                t = threading.Thread(target=ctx.run, args=(self._work, r), daemon=True,
                                     name="clraster-view")
                self.workers.append(t)
                t.start()
            n = 0
            while True:
                with self.lock:
                    while n not in self.done and (self.end is None or n < self.end):
                        self.ready.wait()
                    if n not in self.done:
                        return
                    index, item = self.done.pop(n)
                if index is None:
                    raise item
                self.slots.release()
                yield index, item
                n += 1
        except KeyboardInterrupt:
            interrupted = True
            raise
        finally:
            # the workers joined after the list's end, an error filed at a view or a close;
            # after Ctrl-C in the caller's wait the generator returns at once, the workers
            # finishing their view in the background (`_stop_all_runs` joins them at exit)
            self._stop(join=not interrupted)
            if not interrupted:
                _LIVE_RUNS.discard(self)


def _out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` says memory ran out: Python's MemoryError (host memory, clraster's
    per-buffer limit) or pyopencl's (a device allocation), told by name (this module does
    not import OpenCL)."""
    return isinstance(exc, MemoryError) or type(exc).__name__ == "MemoryError"


def _stop_all_runs() -> None:
    """Before the interpreter exits: stop every run and join its workers, so that none is
    inside an OpenCL call as the interpreter is torn down (a thread waking there then
    aborts the process: `clraster.pipeline.device._drain_waiters`)."""
    for run in list(_LIVE_RUNS):
        run._stop(join=True)


# threading's exit hooks run before atexit's (and before the device waiters are drained)
getattr(threading, "_register_atexit", atexit.register)(_stop_all_runs)


def _render_view(renderer: ViewRenderer[F], target: Any, index: int, cam: Any,
                 render_kwargs: dict) -> F | ViewError:
    """`frames`' view: the frame, or the `ViewError` of a broken or refused camera."""
    if isinstance(cam, BrokenCamera):
        return cam.error
    try:
        return renderer.render(target, cam, **render_kwargs)
    except ValueError as exc:
        err = ViewError(index, None, str(exc))
        err.__cause__ = exc
        return err
