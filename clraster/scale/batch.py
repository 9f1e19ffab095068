"""Render many views of one scene to files (`render_views`) or to arrays (`iter_views`).

One file set per view in ``out_dir``, named by the view's index in the camera list and the
output: ``view_00000_{output}.{format}``. The outputs (`OUTPUTS`; default format first):

======================= ======= ===============================================================
output                  default meaning (`clraster.output.outputs` has each format's encoding)
======================= ======= ===============================================================
depth                   npy     float32 (H, W) window depth, 1.0 background
ids                     npy     int32 (H, W) triangle ids, −1 background
bary                    npy     float32 (H, W, 3) barycentrics
shaded                  png     flat-shaded RGB (`clraster.shade.shade`)
linear_depth            png     depth along the view axis; png: uint16 round(depth ·
                                ``depth_scale``), 0 = no hit (default 1000: millimetres for a
                                scene in metres); npy/npz/tif(f)/exr: float32 scene units, inf
                                on the background
distance                png     distance from the eye along the pixel's ray, as linear_depth
normals                 npy     float32 (H, W, 3) unit world-space face normals, zeros on the
                                background; png: RGB8 round((n + 1)/2 · 255)
smooth_normals          npy     as normals, interpolated area-weighted vertex normals
camera_normals          npy     as normals, in OpenGL eye space (x right, y up, z to the eye)
smooth_camera_normals   npy     both
mask                    png     covered pixels (ids >= 0): png uint8 255 / 0; npy bool
points                  ply     the covered pixels' world positions with their face normals:
                                ply float32 x y z nx ny nz; npy (N, 6) float64; npz points,
                                normals, ids, pixels
======================= ======= ===============================================================

An output takes another format as ``"name:format"`` (``"linear_depth:npy"``,
``"normals:png"``; any extension `clraster.output.outputs.FORMATS` allows for it: png, tif,
tiff, exr, npy, npz, ply), and its file ends in that extension (``view_00000_normals.png``).
The metric depths, normals, masks and point clouds are made on the device by the renderer's
resolve stage (``Renderer.render(..., outputs=...)`` asks for them: `_render_outputs`; exact
surface points in float64, `clraster.pipeline.resolving`), taken through the
`clraster.Frame` methods and written by `clraster.output.outputs.write_output`.
Row 0 is the top row, as in `clraster.Frame`.

Each file is written to a temporary name in ``out_dir`` and renamed into place
(`clraster.atomic.write_atomic`), so a file under its final name is always complete, and a
batch killed halfway leaves no half-written files under those names; the temporaries a
killed run left are deleted by the next run (those of processes of this machine that are
gone, by a run that keeps ``failures.json``: the default; `clraster.distributed.render_views`
deletes all of them when its tasks are done).

What made the files is recorded beside them, so that a re-run never takes files made
otherwise for its own:

* ``render_views.json`` (`MANIFEST_FILE`): the image size and the render options that change
  an image (cull, reversed_z, clip_planes, window; not the culling switches frustum, cones,
  occlusion, which never do), and under ``"outputs"`` how each kind of view file was
  written: its output, format and ``depth_scale`` (for a metric depth PNG), by file suffix
  (``"linear_depth.png": {"depth_scale": 1000.0}``). A run whose size or options differ
  from it, or that would write a file suffix the record lists with another depth_scale,
  raises `OutDirMismatchError`, saying what differs, before anything is rendered; give
  another ``out_dir``, or ``overwrite=True`` to render every view again over the old
  files. Outputs the record does not list yet are added to it (a folder may gather outputs
  over several runs). A folder holding view files but no record is refused the same way.
* ``.view_00000.key`` per view, written after the view's files: a hash of those settings
  and of the view's camera (its view-projection matrix for this size). A re-run skips the
  views whose files all exist under the same key, which is what makes a batch resumable
  (and a Dask task retryable); a view whose camera changed is rendered again (its old
  files deleted first, so a failure leaves none behind).

A view whose camera is broken (a malformed entry, NaN, a singular matrix, near >= far, a
matrix that overflows float32) fails with a message naming its index and field; the rest
of the batch goes on, and the failures come back in the summary (and in
``out_dir/failures.json``). So does a view whose output cannot be written as asked (a
metric depth beyond a 16-bit PNG at this ``depth_scale``: the message names the view, the
output and the depth range); none of its files is left.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from ..base.checks import check_flag
from ..output.atomic import stale_temporary, write_atomic
from ..output.outputs import FORMATS, check_depth_scale, check_writable, write_output
from ..world.inputs import as_target
from ..world.mesh import Mesh
from ..world.views import (
    BrokenCamera,
    ViewError,
    camera_from_entry,
    cameras_in_hand,
    frames,
    iter_cameras,
)

if TYPE_CHECKING:
    from collections.abc import Iterator

    from ..output.frame import Frame
    from ..pipeline.renderer import Renderer
    from ..world.scene import Scene

__all__ = ["MANIFEST_FILE", "OUTPUTS", "OutDirMismatchError", "RenderSummary", "ViewFailure",
           "iter_views", "output_formats", "render_views", "view_arrays", "view_files"]

#: named by the module's public path (users' logging settings name it)
log = logging.getLogger("clraster.batch")

#: output name → its default file extension (another: ``"name:format"``, module docstring)
OUTPUTS = {"depth": ".npy", "ids": ".npy", "bary": ".npy", "shaded": ".png",
           "linear_depth": ".png", "distance": ".png", "normals": ".npy",
           "smooth_normals": ".npy", "camera_normals": ".npy", "smooth_camera_normals": ".npy",
           "mask": ".png", "points": ".ply"}
#: output name → (`clraster.output.outputs` output it is, its ``smooth``, its ``space``)
_WRITTEN_AS = {"depth": ("depth", None, None), "ids": ("ids", None, None),
               "bary": ("bary", None, None), "shaded": ("shaded", None, None),
               "linear_depth": ("linear_depth", None, None),
               "distance": ("distance", None, None), "normals": ("normals", None, None),
               "smooth_normals": ("normals", True, None),
               "camera_normals": ("normals", None, "camera"),
               "smooth_camera_normals": ("normals", True, "camera"),
               "mask": ("mask", None, None), "points": ("points", None, None)}
#: outputs read from the frame's barycentrics on the host (the others need only depth and ids,
#: or are made on the device: `_RESOLVED`)
_NEEDS_BARY = frozenset({"bary", "shaded"})
#: output → the renderer's resolve outputs it is made from (`Renderer.render(outputs=...)`)
_RESOLVED = {"linear_depth": ("linear_depth",), "distance": ("distance",),
             "normals": ("normals",), "smooth_normals": ("smooth_normals",),
             "camera_normals": ("camera_normals",),
             "smooth_camera_normals": ("smooth_camera_normals",), "mask": ("mask",),
             "points": ("points", "normals")}
#: outputs whose PNG is scaled by ``depth_scale``
_SCALED = frozenset({"linear_depth", "distance"})
#: every view file extension (lower case, no dot)
_EXTS = "|".join(sorted((e[1:] for e in FORMATS), key=lambda e: (-len(e), e)))
#: where the failures of the last run are listed (absent when it had none)
FAILURES_FILE = "failures.json"
#: what rendered the files of a folder (size and image-changing options; module docstring)
MANIFEST_FILE = "render_views.json"
#: version of `MANIFEST_FILE`'s layout
MANIFEST_FORMAT = 1
#: `Renderer.render` keywords documented never to change an image (conservative culling,
#: extra outputs): not recorded, so a re-run may change them and still skip. Every other
#: keyword is recorded, a new one included.
IMAGE_NEUTRAL = frozenset({"frustum", "cones", "occlusion", "overdraw", "fates", "outputs"})
#: the names of this module's files in an out_dir, for the temporaries they leave
_OWN_FILE = re.compile(r"^(view_\d+_[a-z_]+\.(" + _EXTS + r")|\.view_\d+\.key|"
                       + re.escape(FAILURES_FILE) + "|" + re.escape(MANIFEST_FILE) + r")$")
#: temporaries of this module before `clraster.atomic` (``.{name}.{pid}.tmp``)
_OLD_TEMPORARY = re.compile(r"^\.(view_\d+_[a-z]+\.(npy|png)|"
                            + re.escape(FAILURES_FILE) + r")\.(?P<pid>\d+)\.tmp$")
#: view files (of any output) in an out_dir
#: a view's key file (`view_key`): ``.view_00042.key``
_KEY_FILE = re.compile(r"^\.view_\d+\.key$")
_VIEW_FILE = re.compile(r"^view_\d+_(" + "|".join(OUTPUTS) + r")\.(" + _EXTS + r")$")


class OutDirMismatchError(ValueError):
    """``out_dir`` holds files rendered with another size or other options (or files no
    record says anything about): re-running into it would mix them with this run's."""


@dataclass(frozen=True)
class ViewFailure:
    """A view that was not rendered: its index in the camera list and why."""

    index: int
    message: str


@dataclass(frozen=True)
class RenderSummary:
    """What `render_views` did.

    views: views in the camera list. rendered: views rendered and written this run.
    skipped: views whose files all existed already, rendered with this run's size, options
    and camera (`clraster.batch`'s record of them). failures: the views that failed, in
    order. seconds: wall time of the run. failures_file: the JSON list of the failures
    (``out_dir/failures.json``), None when there were none.
    """

    views: int
    rendered: int
    skipped: int
    failures: tuple[ViewFailure, ...] = ()
    seconds: float = 0.0
    failures_file: Path | None = field(default=None)

    @property
    def views_per_s(self) -> float:
        """Views rendered (and written) per second of the run."""
        return self.rendered / self.seconds if self.seconds > 0 else 0.0

    @property
    def ok(self) -> bool:
        """True when no view failed."""
        return not self.failures

    def __str__(self) -> str:
        return (f"{self.views} views: {self.rendered} rendered, {self.skipped} skipped, "
                f"{len(self.failures)} failed; {self.seconds:.1f} s, "
                f"{self.views_per_s:.2f} views/s")


def _split(spec: Any) -> tuple[str, str | None]:
    """("name", ".ext" or None) of an output spec "name" or "name:format"."""
    if not isinstance(spec, str):
        raise ValueError(f"an output is a name (or 'name:format'), got {spec!r}")
    name, sep, fmt = spec.partition(":")
    return name.strip(), ("." + fmt.strip().lower().lstrip(".")) if sep else None


def check_outputs(outputs: Sequence[str]) -> tuple[str, ...]:
    """``outputs`` checked: known, distinct output names (`OUTPUTS`), at least one, each
    optionally with a format its output can be written in (``"linear_depth:npy"``). Returns
    them as a tuple of strings, as given (the formats lower-cased)."""
    if isinstance(outputs, str):
        outputs = (outputs,)
    out = tuple(outputs)
    pairs = [_split(o) for o in out]
    names = [n for n, _ in pairs]
    bad = [o for o, n in zip(out, names, strict=True) if n not in OUTPUTS]
    if bad or not out or len(set(names)) != len(names):
        raise ValueError(f"outputs must be distinct names out of {', '.join(OUTPUTS)} (each "
                         f"optionally 'name:format'), at least one; got {list(out)}")
    for spec, (name, ext) in zip(out, pairs, strict=True):
        if ext is None:
            continue
        what = _WRITTEN_AS[name][0]
        if ext not in FORMATS or what not in FORMATS[ext]:
            fits = ", ".join(e[1:] for e, ws in FORMATS.items() if what in ws)
            raise ValueError(f"output {spec!r}: {name} cannot be written as "
                             f"{ext[1:] or '(none)'}; formats for it: {fits}")
    return tuple(n if e is None else f"{n}:{e[1:]}" for n, e in pairs)


def output_formats(outputs: Sequence[str]) -> dict[str, str]:
    """Output name → file extension (".png"...) of checked ``outputs`` (`check_outputs`),
    the default (`OUTPUTS`) where no format is named."""
    return {n: e or OUTPUTS[n] for n, e in map(_split, check_outputs(outputs))}


def view_files(out_dir: str | os.PathLike, index: int, outputs: Sequence[str]
               ) -> dict[str, Path]:
    """Output name → path of view ``index``'s files (``view_00042_depth.npy``, with
    ``"normals:png"`` ``view_00042_normals.png``...)."""
    d = Path(out_dir)
    return {n: d / f"view_{index:05d}_{n}{e}" for n, e in output_formats(outputs).items()}


def _all_view_files(out: Path, index: int) -> list[Path]:
    """Every view file of view ``index`` there is in ``out`` (any output, any format)."""
    prefix = f"view_{index:05d}_"
    return [out / f"{prefix}{n}.{e}" for n in OUTPUTS for e in _EXTS.split("|")
            if (out / f"{prefix}{n}.{e}").exists()]


def check_output_depth_scale(outputs: Sequence[str], depth_scale: float | None) -> float | None:
    """``depth_scale`` checked against checked ``outputs``: None when no output reads it;
    1000.0 when one does and it was not given. A depth_scale that no output reads (none is
    linear_depth / distance written as PNG) is refused, never ignored."""
    reads = [n for n, e in output_formats(outputs).items() if n in _SCALED and e == ".png"]
    if depth_scale is None:
        return 1000.0 if reads else None
    scale = check_depth_scale(depth_scale)
    if not reads:
        raise ValueError(f"depth_scale={depth_scale!r} is read only by linear_depth or "
                         f"distance written as png (uint16 = round(depth * depth_scale)); "
                         f"outputs {list(outputs)} have none: leave it out")
    return scale


def check_writable_outputs(outputs: Sequence[str]) -> None:
    """Refuse a format this installation cannot write for one of checked ``outputs`` (EXR
    without a plugin, a float (H, W, 3) TIFF without tifffile:
    `clraster.output.outputs.check_writable`), once before any view is rendered."""
    for name, ext in output_formats(outputs).items():
        check_writable(_WRITTEN_AS[name][0], ext)


def outputs_record(outputs: Sequence[str], depth_scale: float | None) -> dict[str, dict]:
    """How checked ``outputs`` write their files, for `MANIFEST_FILE`: file suffix
    (``"linear_depth.png"``) → its options (``{"depth_scale": 1000.0}`` for a scaled PNG,
    else ``{}``)."""
    scale = check_output_depth_scale(outputs, depth_scale)
    return {f"{n}{e}": ({"depth_scale": scale} if n in _SCALED and e == ".png" else {})
            for n, e in output_formats(outputs).items()}


def _write_atomic(path: Path, write) -> None:
    """``write(file object)`` into a temporary file beside ``path``, then rename it over
    ``path`` (`clraster.atomic.write_atomic`)."""
    write_atomic(path, write)


def _marker(out: Path, index: int) -> Path:
    return out / f".view_{index:05d}.key"


def _jsonable(value: Any) -> Any:
    """``value`` (an option: str, bool, number, None, arrays and nested sequences) as JSON
    data, the same for equal values whatever their container (tuple, list, ndarray)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if value is None or isinstance(value, (str, bool, int, float)):
        return value
    return repr(value)


def check_camera_size(cameras: Sequence[Any], width: int, height: int) -> None:
    """ValueError now, not one failed view per camera, when the size-bound cameras of the
    list (intrinsics cameras: `clraster.world.camera_files.common_size`) are for images of
    another size than ``width`` × ``height``."""
    from ..world.camera_files import common_size

    own = common_size([c for c in cameras if not isinstance(c, BrokenCamera)])
    if own is not None and own != (width, height):
        raise ValueError(f"the cameras are for {own[0]}x{own[1]} images (their K is in those "
                         f"pixels), not the {width}x{height} asked for: pass size={own}")


def scene_fingerprint(target: Mesh | Scene) -> str:
    """A hash of what ``target`` draws (every mesh's vertices and faces, every instance's
    mesh and transform, in order), recorded as the run's ``scene``: a re-run with an edited
    or another scene is a mismatch, not a folder of done views. ~10 ms per million
    triangles."""
    h = hashlib.blake2b(digest_size=16)

    def mesh(m: Mesh) -> None:
        for a in (m.vertices, m.faces):
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(np.ascontiguousarray(a).tobytes())

    # a Mesh hashes as the one-instance scene it renders like (a file loaded as a Mesh on
    # one machine and as a Scene on a Dask worker is the same scene)
    placed = ([(target, np.eye(4))] if isinstance(target, Mesh)
              else [(inst.mesh, inst.transform) for inst in target.instances])
    seen: dict[int, int] = {}
    for m, transform in placed:
        k = seen.get(id(m))
        if k is None:       # a mesh shared by many instances is hashed once
            k = seen[id(m)] = len(seen)
            mesh(m)
        h.update(f"i{k}".encode())
        h.update(np.ascontiguousarray(transform, dtype="<f8").tobytes())
    return h.hexdigest()


def run_settings(width: int, height: int, render_kwargs: dict[str, Any],
                 scene: str | None = None) -> dict[str, Any]:
    """What `MANIFEST_FILE` records for a run (JSON data): ``size`` [width, height], the
    ``scene`` (`scene_fingerprint`, where given) and every `Renderer.render` option but
    `IMAGE_NEUTRAL` ones, defaults filled in (``cull="back"`` given or left out records the
    same). ``render_kwargs`` must have passed `clraster.renderer.check_render_kwargs`."""
    import inspect

    from ..base.checks import check_clip_planes
    from ..pipeline.renderer import Renderer

    bound = inspect.signature(Renderer.render).bind(None, None, None, **render_kwargs)
    bound.apply_defaults()
    options = {k: v for k, v in list(bound.arguments.items())[3:] if k not in IMAGE_NEUTRAL}
    if "clip_planes" in options:   # None, [] and a (4,) plane as render reads them
        options["clip_planes"] = check_clip_planes(options["clip_planes"])
    if options.get("window") is not None:   # any accepted form: its normalised rings
        from ..clip.clip2d import as_polygon

        poly = as_polygon(options["window"])
        options["window"] = {"exterior": poly.exterior, "holes": list(poly.holes)}
    return {"size": [int(width), int(height)],
            **({} if scene is None else {"scene": scene}),
            **{k: _jsonable(v) for k, v in sorted(options.items())}}


def _settings_text(settings: dict[str, Any]) -> str:
    return json.dumps(settings, sort_keys=True, separators=(",", ":"), allow_nan=True)


def view_key(settings: dict[str, Any], matrix: np.ndarray) -> str:
    """A view's key (``.view_NNNNN.key``): a hash of ``settings`` (`run_settings`) and its
    float64 (4, 4) view-projection ``matrix``."""
    h = hashlib.blake2b(_settings_text(settings).encode("utf-8"), digest_size=16)
    h.update(np.ascontiguousarray(matrix, dtype="<f8").tobytes())
    return h.hexdigest()


def _camera_matrix(cam: Any, width: int, height: int) -> np.ndarray | None:
    """float64 (4, 4) view-projection of a camera list item for this size, or None for an
    item that cannot make one (it fails its view when rendered)."""
    if isinstance(cam, BrokenCamera):
        return None
    try:
        if isinstance(cam, dict):
            cam = camera_from_entry(cam, 0)
        m = np.asarray(cam.view_projection(width, height), np.float64)
    except Exception:   # anything the view itself will report (or raise) when rendered
        return None
    return m if m.shape == (4, 4) and np.all(np.isfinite(m)) else None


def _differences(there: dict[str, Any], here: dict[str, Any]) -> list[str]:
    out = []
    for k in sorted(set(there) | set(here), key=lambda k: (k != "size", k)):
        a, b = there.get(k, "<not recorded>"), here.get(k, "<not recorded>")
        if a != b:   # (a window's rings can be long: their start says enough)
            out.append(f"{k}: {_short(a)} there, {_short(b)} now")
    return out


def _short(value: Any, n: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= n else text[:n - 3] + "..."


def _read_record(text: str | None) -> tuple[dict | None, dict]:
    """(settings, outputs record) of a `MANIFEST_FILE`'s text; settings None when it cannot
    be read. A record without "outputs" (written before outputs were recorded) lists none."""
    try:
        old = json.loads(text or "")
        there = old["settings"] if old.get("format") == MANIFEST_FORMAT else None
        files = old.get("outputs", {})
    except (ValueError, AttributeError, KeyError, TypeError):
        return None, {}
    if not isinstance(there, dict):
        return None, {}
    return there, files if isinstance(files, dict) else {}


def prepare_out_dir(out_dir: str | os.PathLike, settings: dict[str, Any], *,
                    overwrite: bool = False, outputs: dict[str, dict] | None = None) -> None:
    """Check ``out_dir`` (an existing folder) against ``settings`` (`run_settings`) and
    ``outputs`` (`outputs_record`: how this run writes its files), and record them in its
    `MANIFEST_FILE` (atomically; left alone when it says the same). Outputs recorded by
    earlier runs and not written by this one stay in the record.

    Raises:
        OutDirMismatchError: (unless ``overwrite``) the folder's record holds another size
            or other options, or lists one of this run's file suffixes with other output
            options (depth_scale; the message lists them), cannot be read, or is missing
            while view files are there.
    """
    out = Path(out_dir)
    path = out / MANIFEST_FILE
    try:
        old_text: str | None = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        old_text = None
    there, files = _read_record(old_text)
    here = dict(outputs or {})
    if there == settings:   # files of the same settings: this run's outputs join them
        here = {**files, **here}

    def manifest_text() -> str:
        manifest = {"written_by": "clraster.batch.render_views", "format": MANIFEST_FORMAT,
                    "settings": settings, "outputs": here}
        return json.dumps(manifest, indent=1, sort_keys=True) + "\n"

    text = manifest_text()
    if old_text == text:
        return
    what = ("give another out_dir, delete this folder's files, or pass overwrite=True to "
            "render every view again over them")
    if not overwrite and old_text is None:
        if any(_VIEW_FILE.match(p.name) for p in out.iterdir()):
            raise OutDirMismatchError(
                f"out_dir {str(out)!r} holds view files but no {MANIFEST_FILE} saying what "
                f"rendered them (another program, or an older clraster), so "
                f"they cannot be told from this run's: {what}")
    elif not overwrite:
        if there is None:
            raise OutDirMismatchError(f"{str(path)!r} is not a record this version of "
                                      f"clraster can read (format {MANIFEST_FORMAT}): {what}")
        diff = _differences(there, settings)
        diff += [f"{suffix} files: {_short(files[suffix])} there, {_short(opts)} now"
                 for suffix, opts in sorted((outputs or {}).items())
                 if suffix in files and files[suffix] != opts]
        if diff:
            raise OutDirMismatchError(
                f"out_dir {str(out)!r} holds views rendered with other settings "
                f"({'; '.join(diff)}; recorded in {MANIFEST_FILE}): {what}")
    elif there != settings:
        # overwrite with other settings: the folder's views all go, not only this run's
        # cameras', so that no file is left under a record that does not describe it
        for p in out.iterdir():
            if _VIEW_FILE.match(p.name) or _KEY_FILE.match(p.name):
                p.unlink(missing_ok=True)
    write_atomic(path, text.encode("utf-8"))


def remove_temporaries(out_dir: str | os.PathLike, *, any_writer: bool = False) -> int:
    """Delete the temporary files this module's writers left in ``out_dir`` (their own
    naming pattern only, never another file): those of processes of this machine that are
    gone, or with ``any_writer`` (no writer of the folder left anywhere: the end of a Dask
    run) all of them. Returns how many were deleted."""
    from ..output.atomic import pid_alive

    gone = 0
    for p in Path(out_dir).iterdir():
        final = stale_temporary(p.name, any_writer=any_writer)
        if final is not None:
            dead = bool(_OWN_FILE.match(final))
        else:
            m = _OLD_TEMPORARY.match(p.name)
            dead = m is not None and (any_writer or not pid_alive(int(m["pid"])))
        if dead:
            try:
                p.unlink()
                gone += 1
            except FileNotFoundError:
                pass
    return gone


def _write_options(name: str, ext: str, target: Any, camera: Any,
                   depth_scale: float | None) -> tuple[str, dict[str, Any]]:
    """(`clraster.output.outputs` output, `write_output` keywords) of output ``name`` written
    as ``ext``: only the options it reads (write_output refuses the others)."""
    what, smooth, space = _WRITTEN_AS[name]
    kw: dict[str, Any] = {}
    if what in ("linear_depth", "distance"):
        kw = {"camera": camera, "target": target}
        if ext == ".png":
            kw["depth_scale"] = depth_scale
    elif what in ("normals", "points", "shaded"):
        kw = {"target": target}
        if smooth:
            kw["smooth"] = True
        if space == "camera":
            kw.update(space="camera", camera=camera)
    return what, kw


def _write_view(files: dict[str, Path], frame: Frame, target: Any, camera: Any,
                depth_scale: float | None, index: int) -> None:
    """Write the view's files (`clraster.output.outputs.write_output`). An output that cannot
    be written as asked (a ValueError: a depth beyond a 16-bit PNG...) is the view's
    failure: its files written so far are deleted and a `ViewError` naming it is raised."""
    for name, path in files.items():
        what, kw = _write_options(name, path.suffix.lower(), target, camera, depth_scale)
        try:
            write_output(path, frame, what, **kw)
        except ValueError as exc:
            for p in files.values():
                p.unlink(missing_ok=True)
            raise ViewError(index, None, f"output {name} ({path.name}): {exc}") from exc


def view_arrays(frame: Frame, camera: Any, target: Any, outputs: Sequence[str]
                ) -> dict[str, np.ndarray]:
    """Output name → array of one rendered view, from the `clraster.Frame` methods (the
    device-made arrays where the frame has them, `_render_outputs`, else host NumPy; float64
    surface points either way; the same values the files of `render_views` hold before
    encoding): depth, ids (int32), bary, mask (bool), shaded (uint8) as the frame has them;
    linear_depth / distance float32 (H, W) scene units, inf background
    (``frame.linear_depth(camera, target)``); normals and its variants float32 (H, W, 3);
    points (N, 6) float64, columns x y z nx ny nz (world positions and face normals of the
    covered pixels in row-major order: ``frame.points(target)``, ``frame.point_normals``).
    ``outputs``: names of `OUTPUTS` (no formats)."""
    out: dict[str, np.ndarray] = {}
    for name in outputs:
        what, smooth, space = _WRITTEN_AS[name]
        if what == "depth":
            out[name] = frame.depth
        elif what == "ids":
            out[name] = frame.triangle_id
        elif what == "bary":
            out[name] = frame.need_barycentrics()
        elif what == "mask":
            out[name] = frame.mask
        elif what == "shaded":
            from ..output.shade import shade

            out[name] = shade(frame, target)
        elif what == "linear_depth":
            out[name] = frame.linear_depth(camera, target)
        elif what == "distance":
            out[name] = frame.distance(camera, target)
        elif what == "normals":
            out[name] = frame.normals(target, smooth=bool(smooth), space=space or "world",
                                      camera=camera if space == "camera" else None)
        else:
            xyz = frame.points(target).points
            out[name] = np.hstack([xyz, frame.point_normals(target).astype(np.float64)])
    return out


def _render_outputs(outs: Sequence[str], render_kwargs: dict[str, Any]) -> dict[str, Any]:
    """``render_kwargs`` with the renderer's ``outputs`` (unless the caller gave them): depth
    and ids, the barycentrics only where an output reads them on the host (shaded, bary;
    else 8 bytes a pixel are kept instead of 20), and the resolve outputs the device makes
    for the others (`_RESOLVED`: no host pass over the frame)."""
    if "outputs" in render_kwargs:
        return render_kwargs
    names = [_split(o)[0] for o in outs]
    want = ["depth", "ids"] + (["bary"] if any(n in _NEEDS_BARY for n in names) else [])
    for n in names:
        want += [r for r in _RESOLVED.get(n, ()) if r not in want]
    return {**render_kwargs, "outputs": tuple(want)}


def _checked_cameras(cams: Sequence[Any], width: int, height: int) -> list[Any]:
    """The cameras of a list as `clraster.world.views.iter_cameras` makes them (entry dicts
    made into cameras, broken ones `BrokenCamera`): what each view was rendered with, for
    the outputs that read the camera."""
    return [c for _, c in iter_cameras(cams, width, height)]


def iter_views(target: Any, cameras: Iterable[Any] | str | os.PathLike,
               outputs: Sequence[str] = ("depth", "ids"), *, renderer: Renderer | None = None,
               size: tuple[int, int] = (640, 480), errors: str = "raise",
               **render_kwargs: Any) -> Iterator[dict[str, Any]]:
    """Render ``target`` from each camera in turn and yield its outputs as arrays, for a
    training loop that wants no files: one dict per view, output name → array
    (`view_arrays`: the `clraster.Frame` methods, computed on the host), plus ``"index"``
    (the view's place in ``cameras``) and ``"camera"`` (the camera it was rendered with).

    The arrays are the caller's (never reused by the renderer). From a list of cameras
    or a camera file, up to three views are rendered ahead of the loop, two at a time
    (`clraster.RasterConfig.views_in_flight`); from any other iterable (a generator that
    picks the next camera from the last view, say) each camera is read and rendered when
    the next dict is asked for. Example::

        for v in iter_views(mesh, cams, ("linear_depth", "normals", "mask"), size=(640, 480)):
            train_step(v["linear_depth"], v["normals"], v["mask"])

    Args:
        target: a `clraster.Mesh` / `clraster.Scene` / trimesh object.
        cameras: as `render_views` (a list, an iterable read one camera at a time, or a
            camera file).
        outputs: names out of `OUTPUTS` (no ``":format"``: nothing is written).
        renderer: a `clraster.Renderer` (its size is used); default a new one of ``size``.
        errors: "raise" (default): a broken camera raises its `ViewError` (naming its index
            and field); "skip": it is logged as a warning and left out.
        render_kwargs: `Renderer.render`'s keywords (cull, reversed_z, ...).

    Raises:
        ValueError / TypeError: bad outputs, errors or keywords, before anything is
        rendered; ViewError (a ValueError): a broken camera, with ``errors="raise"``.
    """
    from ..pipeline.renderer import Renderer, check_render_kwargs

    outs = check_outputs(outputs)
    formats = [o for o in outs if ":" in o]
    if formats:
        raise ValueError(f"iter_views yields arrays, not files: outputs {formats} name a "
                         f"format; give the names alone")
    if errors not in ("raise", "skip"):
        raise ValueError(f"errors must be 'raise' or 'skip', got {errors!r}")
    geometry = as_target(target)
    if renderer is None:
        renderer = Renderer(*size)
    check_render_kwargs(renderer, render_kwargs)
    kwargs = _render_outputs(outs, render_kwargs)
    return _iter_views(renderer, geometry, target, cameras, outs, errors, kwargs)


def _iter_views(renderer: Renderer, geometry: Any, target: Any, cameras: Any,
                outs: tuple[str, ...], errors: str, kwargs: dict[str, Any]
                ) -> Iterator[dict[str, Any]]:
    checked = ((i, c) for i, c in iter_cameras(cameras, renderer.width, renderer.height))
    pending: list[tuple[int, Any]] = []

    def cams() -> Iterator[Any]:   # the cameras, read one at a time, remembered for the frame
        for i, c in checked:
            pending.append((i, c))
            yield c

    # read ahead (two views in flight) only from a list or file in hand
    partner = _partner(renderer, geometry, kwargs) if cameras_in_hand(cameras) else None
    for _, item in frames(renderer, geometry, cams(), kwargs, partner):
        index, cam = pending.pop(0)
        if isinstance(item, ViewError):
            if errors == "raise":
                raise item
            log.warning("%s", item)
            continue
        yield {"index": index, "camera": cam, **view_arrays(item, cam, target, outs)}


def _partner(renderer: Any, geometry: Any, render_kwargs: dict[str, Any]) -> Any:
    """``renderer``'s `Renderer.view_partner` for these views (two in flight), or None
    (a renderer without one, such as the NumPy twin's, renders them one at a time)."""
    make = getattr(renderer, "view_partner", None)
    return make(geometry, render_kwargs) if make is not None else None


def write_failures(path: Path, failures: Sequence[ViewFailure]) -> None:
    """The JSON list ``[{"index": ..., "message": ...}, ...]`` of ``failures``, atomically."""
    text = json.dumps([{"index": f.index, "message": f.message} for f in failures], indent=1)
    _write_atomic(path, lambda fh: fh.write(text.encode("utf-8")))


class _Progress:
    """A one-line progress bar on a stream, redrawn at most ~10 times a second."""

    def __init__(self, stream: TextIO, total: int | None) -> None:
        self.stream, self.total = stream, total
        self.t0 = self.last = time.perf_counter()

    def update(self, done: int, rendered: int, failed: int, final: bool = False) -> None:
        now = time.perf_counter()
        if not final and now - self.last < 0.1:
            return
        self.last = now
        rate = rendered / (now - self.t0) if now > self.t0 else 0.0
        if self.total:
            filled = int(30 * done / self.total)
            bar = f"[{'#' * filled}{'.' * (30 - filled)}] {done}/{self.total}"
        else:
            bar = f"{done}"
        tail = f" views  {rate:.1f} views/s" + (f"  {failed} failed" if failed else "")
        self.stream.write(f"\r{bar}{tail}\x1b[K" + ("\n" if final else ""))
        self.stream.flush()


def render_views(target: Any, cameras: Iterable[Any] | str | os.PathLike,
                 out_dir: str | os.PathLike, outputs: Sequence[str] = ("depth", "ids"), *,
                 size: tuple[int, int] = (640, 480), renderer: Renderer | None = None,
                 start: int = 0, progress: bool | None = None, failures_file: bool = True,
                 overwrite: bool = False, depth_scale: float | None = None,
                 **render_kwargs: Any) -> RenderSummary:
    """Render ``target`` (a `clraster.Mesh` or `clraster.Scene`) from every camera and write
    one file set per view into ``out_dir`` (names and formats: the module docstring).

    Args:
        cameras: a list of cameras (`clraster.Camera`, camera entry dicts, objects with
            ``view_projection``) or the path of a camera list file (`clraster.views`).
        out_dir: created if missing (its parent must exist). What rendered its files is
            recorded in it (module docstring); a folder rendered with another size or
            other image options is refused.
        outputs: names out of `OUTPUTS` (depth, ids, bary, shaded, linear_depth, distance,
            normals, smooth_normals, camera_normals, smooth_camera_normals, mask, points),
            each optionally ``"name:format"`` (module docstring).
        size: (width, height) of the images, when no ``renderer`` is given.
        renderer: a `clraster.Renderer` to render with (its size is used); default a new
            one of ``size``.
        start: index of ``cameras[0]`` in the whole list, for file names, when a list is
            split into chunks rendered apart (e.g. one Dask task per chunk).
        progress: a progress bar on stderr; default only when stderr is a terminal.
        failures_file: write (or remove) ``out_dir/failures.json`` and delete the
            temporaries of dead writers first; False leaves both alone, for chunks of one
            list run side by side (`clraster.distributed.render_views` writes the merged
            list once and deletes the temporaries at the end).
        overwrite: render every view again, even those whose files are there, and record
            this run's settings over a folder's old ones (instead of refusing them).
        depth_scale: linear_depth / distance PNG units per scene unit: PNG value =
            ``round(depth · depth_scale)``, 0 = no hit; default 1000 (millimetres for a
            scene in metres). A depth that does not fit 1..65535 fails its view (the message
            names the view and the depth range), never wraps. Refused when no output is a
            linear_depth / distance PNG. Recorded in the folder (module docstring).
        render_kwargs: `Renderer.render`'s keywords (cull, frustum, cones, occlusion, ...).

    Returns:
        a `RenderSummary` (views, rendered, skipped, failures, views/s). Skipped: views
        whose files all exist under the key of this run's settings and camera.

    Raises:
        ValueError / TypeError: bad outputs, formats, depth_scale, target, keywords or
            keyword values (cull, clip_planes, reversed_z, ...: the checks
            `Renderer.render` makes), a format this installation cannot write (EXR without
            a plugin...), all before anything is rendered; OutDirMismatchError (a
            ValueError): ``out_dir`` holds views of another size or other options, or
            files of its outputs written with another depth_scale (module docstring);
            CameraFileError: a camera list file that is not a list of entries. Errors
            writing files (OSError) stop the batch.
    """
    from ..pipeline.renderer import Renderer, check_render_kwargs

    outs = check_outputs(outputs)
    record = outputs_record(outs, depth_scale)
    scale = check_output_depth_scale(outs, depth_scale)
    check_writable_outputs(outs)
    geometry = as_target(target)   # rendered; ``target`` itself is shaded (its colours)
    if isinstance(start, bool) or not isinstance(start, int) or start < 0:
        raise ValueError(f"start must be an integer >= 0, got {start!r}")
    if renderer is None:
        renderer = Renderer(*size)
    check_render_kwargs(renderer, render_kwargs)   # names and values, once for all views
    check_flag(overwrite, "overwrite")
    settings = run_settings(renderer.width, renderer.height, render_kwargs,
                            scene_fingerprint(geometry))
    render_kwargs = _render_outputs(outs, render_kwargs)
    if isinstance(cameras, (str, os.PathLike)):
        from ..world.views import load_cameras

        cameras = load_cameras(cameras, strict=False, size=(renderer.width, renderer.height))
    cams = cameras if isinstance(cameras, Sequence) else list(cameras)
    check_camera_size(cams, renderer.width, renderer.height)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir {str(out)!r} exists and is not a folder")
    if not out.parent.is_dir():
        raise ValueError(f"out_dir {str(out)!r}: folder {str(out.parent)!r} does not exist")
    out.mkdir(exist_ok=True)
    prepare_out_dir(out, settings, overwrite=overwrite, outputs=record)
    if failures_file:
        # a run killed earlier (SIGKILL: nothing ran to clean up) left its temporaries here.
        # Not per chunk (failures_file=False): each would scan the whole folder, and
        # clraster.distributed.render_views deletes them all once its tasks are done
        remove_temporaries(out)
    show = sys.stderr.isatty() if progress is None else bool(progress)
    bar = _Progress(sys.stderr, len(cams)) if show else None

    t0 = time.perf_counter()
    failures: list[ViewFailure] = []
    rendered = skipped = 0
    # (index in the caller's list, camera, key, key of the files there) of the views to render
    todo: list[tuple[int, Any, str | None, str | None]] = []
    for k, cam in enumerate(cams):
        index = start + k
        m = _camera_matrix(cam, renderer.width, renderer.height)
        key = None if m is None else view_key(settings, m)
        try:
            old: str | None = _marker(out, index).read_text(encoding="utf-8").strip()
        except (FileNotFoundError, UnicodeDecodeError):
            old = None
        if (not overwrite and key is not None and old == key
                and all(p.exists() for p in view_files(out, index, outs).values())):
            skipped += 1
        else:
            todo.append((k, cam, key, old))
    checked = _checked_cameras([t[1] for t in todo], renderer.width, renderer.height)
    views = frames(renderer, geometry, checked, render_kwargs,
                   _partner(renderer, geometry, render_kwargs))
    for done, (k, item) in enumerate(views, start=skipped + 1):
        _, _, key, old = todo[k]
        index = start + todo[k][0]
        if key is None or old != key:
            # files made with another camera or settings (or whose maker is unknown) are
            # not this view's: gone before anything is written, so that neither a failure
            # now nor a kill halfway leaves them looking done
            _marker(out, index).unlink(missing_ok=True)
            for p in _all_view_files(out, index):
                p.unlink(missing_ok=True)
        if not isinstance(item, ViewError):
            try:
                _write_view(view_files(out, index, outs), item, target, checked[k], scale,
                            index)
            except ViewError as exc:
                item = exc
        if isinstance(item, ViewError):
            # the engine numbers the views it was given; name the entry in the caller's list
            err = ViewError(index, item.field, item.message)
            failures.append(ViewFailure(index, str(err)))
            log.warning("%s", err)
        else:
            if key is not None:   # last: the view is done once its key is there
                _write_atomic(_marker(out, index), lambda fh, t=key: fh.write(t.encode()))
            rendered += 1
        if bar:
            bar.update(done, rendered, len(failures))
    seconds = time.perf_counter() - t0
    if bar:
        bar.update(len(cams), rendered, len(failures), final=True)
    ffile = out / FAILURES_FILE if failures_file else None
    if ffile is not None and failures:
        write_failures(ffile, failures)
    elif ffile is not None:
        ffile.unlink(missing_ok=True)   # an earlier run's list is no longer true
    return RenderSummary(len(cams), rendered, skipped, tuple(failures), seconds,
                         ffile if failures else None)
