"""Render many views of one scene to files: `render_views`.

One file set per view in ``out_dir``, named by the view's index in the camera list:
``view_00000_depth.npy`` (float32 (H, W) window depth, 1.0 background),
``view_00000_ids.npy`` (int32 (H, W) triangle ids, −1 background),
``view_00000_bary.npy`` (float32 (H, W, 3) barycentrics) and ``view_00000_shaded.png``
(flat-shaded RGB, `clraster.shade.shade`). Row 0 is the top row, as in
`clraster.Frame`. Each file is written to a temporary name in ``out_dir`` and renamed into
place (`clraster.atomic.write_atomic`), so a file under its final name is always complete,
and a batch killed halfway leaves no half-written files under those names; the temporaries
a killed run left are deleted by the next run (those of processes of this machine that are
gone, by a run that keeps ``failures.json``: the default; `clraster.distributed.render_views`
deletes all of them when its tasks are done).

What made the files is recorded beside them, so that a re-run never takes files made
otherwise for its own:

* ``render_views.json`` (`MANIFEST_FILE`): the image size and the render options that change
  an image (cull, reversed_z, clip_planes, window; not the culling switches frustum, cones,
  occlusion, which never do). A run whose size or options differ from it raises
  `OutDirMismatchError`, saying what differs, before anything is rendered; give another
  ``out_dir``, or ``overwrite=True`` to render every view again over the old files. A
  folder holding view files but no record is refused the same way.
* ``.view_00000.key`` per view, written after the view's files: a hash of those settings
  and of the view's camera (its view-projection matrix for this size). A re-run skips the
  views whose files all exist under the same key, which is what makes a batch resumable
  (and a Dask task retryable); a view whose camera changed is rendered again (its old
  files deleted first, so a failure leaves none behind).

A view whose camera is broken (a malformed entry, NaN, a singular matrix, near >= far, a
matrix that overflows float32) fails with a message naming its index and field; the rest
of the batch goes on, and the failures come back in the summary (and in
``out_dir/failures.json``).
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
from ..world.inputs import as_target
from ..world.views import BrokenCamera, ViewError, camera_from_entry, frames

if TYPE_CHECKING:
    from ..output.frame import Frame
    from ..pipeline.renderer import Renderer

__all__ = ["MANIFEST_FILE", "OUTPUTS", "OutDirMismatchError", "RenderSummary", "ViewFailure",
           "render_views", "view_files"]

#: named by the module's public path (users' logging settings name it)
log = logging.getLogger("clraster.batch")

#: output name → file suffix
OUTPUTS = {"depth": ".npy", "ids": ".npy", "bary": ".npy", "shaded": ".png"}
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
_OWN_FILE = re.compile(r"^(view_\d+_[a-z]+\.(npy|png)|\.view_\d+\.key|"
                       + re.escape(FAILURES_FILE) + "|" + re.escape(MANIFEST_FILE) + r")$")
#: temporaries of this module before `clraster.atomic` (``.{name}.{pid}.tmp``)
_OLD_TEMPORARY = re.compile(r"^\.(view_\d+_[a-z]+\.(npy|png)|"
                            + re.escape(FAILURES_FILE) + r")\.(?P<pid>\d+)\.tmp$")
#: view files (of any output) in an out_dir
_VIEW_FILE = re.compile(r"^view_\d+_(" + "|".join(OUTPUTS) + r")\.(npy|png)$")


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


def check_outputs(outputs: Sequence[str]) -> tuple[str, ...]:
    """``outputs`` as a tuple of known, distinct output names (`OUTPUTS`), at least one."""
    if isinstance(outputs, str):
        outputs = (outputs,)
    out = tuple(outputs)
    bad = [o for o in out if o not in OUTPUTS]
    if bad or not out or len(set(out)) != len(out):
        raise ValueError(f"outputs must be distinct names out of {', '.join(OUTPUTS)}, "
                         f"at least one; got {list(out)}")
    return out


def view_files(out_dir: str | os.PathLike, index: int, outputs: Sequence[str]
               ) -> dict[str, Path]:
    """Output name → path of view ``index``'s files (``view_00042_depth.npy``...)."""
    d = Path(out_dir)
    return {o: d / f"view_{index:05d}_{o}{OUTPUTS[o]}" for o in outputs}


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


def run_settings(width: int, height: int, render_kwargs: dict[str, Any]) -> dict[str, Any]:
    """What `MANIFEST_FILE` records for a run (JSON data): ``size`` [width, height] and every
    `Renderer.render` option but `IMAGE_NEUTRAL` ones, defaults filled in (``cull="back"``
    given or left out records the same). ``render_kwargs`` must have passed
    `clraster.renderer.check_render_kwargs`."""
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


def prepare_out_dir(out_dir: str | os.PathLike, settings: dict[str, Any], *,
                    overwrite: bool = False) -> None:
    """Check ``out_dir`` (an existing folder) against ``settings`` (`run_settings`) and
    record them in its `MANIFEST_FILE` (atomically; left alone when it says the same).

    Raises:
        OutDirMismatchError: (unless ``overwrite``) the folder's record holds another size
            or other options (the message lists them), cannot be read, or is missing while
            view files are there.
    """
    out = Path(out_dir)
    path = out / MANIFEST_FILE
    manifest = {"written_by": "clraster.batch.render_views", "format": MANIFEST_FORMAT,
                "settings": settings}
    text = json.dumps(manifest, indent=1, sort_keys=True) + "\n"
    try:
        old_text: str | None = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        old_text = None
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
        try:
            old = json.loads(old_text or "")
            there = old["settings"] if old.get("format") == MANIFEST_FORMAT else None
        except (ValueError, AttributeError, KeyError, TypeError):
            there = None
        if not isinstance(there, dict):
            raise OutDirMismatchError(f"{str(path)!r} is not a record this version of "
                                      f"clraster can read (format {MANIFEST_FORMAT}): {what}")
        diff = _differences(there, settings)
        if diff:
            raise OutDirMismatchError(
                f"out_dir {str(out)!r} holds views rendered with other settings "
                f"({'; '.join(diff)}; recorded in {MANIFEST_FILE}): {what}")
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


def _write_view(files: dict[str, Path], frame: Frame, target: Any) -> None:
    arrays = {"depth": frame.depth, "ids": frame.triangle_id, "bary": frame.barycentrics}
    for name, path in files.items():
        if name == "shaded":
            from PIL import Image

            from ..output.shade import shade

            image = shade(frame, target)
            _write_atomic(path, lambda fh, im=image: Image.fromarray(im).save(fh, "PNG"))
        else:
            _write_atomic(path, lambda fh, a=arrays[name]: np.save(fh, a))


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
                 overwrite: bool = False, **render_kwargs: Any) -> RenderSummary:
    """Render ``target`` (a `clraster.Mesh` or `clraster.Scene`) from every camera and write
    one file set per view into ``out_dir`` (names and formats: the module docstring).

    Args:
        cameras: a list of cameras (`clraster.Camera`, camera entry dicts, objects with
            ``view_projection``) or the path of a camera list file (`clraster.views`).
        out_dir: created if missing (its parent must exist). What rendered its files is
            recorded in it (module docstring); a folder rendered with another size or
            other image options is refused.
        outputs: any of "depth", "ids", "bary", "shaded".
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
        render_kwargs: `Renderer.render`'s keywords (cull, frustum, cones, occlusion, ...).

    Returns:
        a `RenderSummary` (views, rendered, skipped, failures, views/s). Skipped: views
        whose files all exist under the key of this run's settings and camera.

    Raises:
        ValueError / TypeError: bad outputs, target, keywords or keyword values (cull,
            clip_planes, reversed_z, ...: the checks `Renderer.render` makes), all before
            anything is rendered; OutDirMismatchError (a ValueError): ``out_dir`` holds
            views of another size or other options (module docstring); CameraFileError: a
            camera list file that is not a list of entries. Errors writing files (OSError)
            stop the batch.
    """
    from ..pipeline.renderer import Renderer, check_render_kwargs

    outs = check_outputs(outputs)
    geometry = as_target(target)   # rendered; ``target`` itself is shaded (its colours)
    if isinstance(start, bool) or not isinstance(start, int) or start < 0:
        raise ValueError(f"start must be an integer >= 0, got {start!r}")
    if renderer is None:
        renderer = Renderer(*size)
    check_render_kwargs(renderer, render_kwargs)   # names and values, once for all views
    check_flag(overwrite, "overwrite")
    settings = run_settings(renderer.width, renderer.height, render_kwargs)
    if "bary" not in outs and "shaded" not in outs and "outputs" not in render_kwargs:
        # no file needs the barycentrics: 8 bytes a pixel are made instead of 20
        render_kwargs = {**render_kwargs, "outputs": ("depth", "ids")}
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir {str(out)!r} exists and is not a folder")
    if not out.parent.is_dir():
        raise ValueError(f"out_dir {str(out)!r}: folder {str(out.parent)!r} does not exist")
    out.mkdir(exist_ok=True)
    prepare_out_dir(out, settings, overwrite=overwrite)
    if failures_file:
        # a run killed earlier (SIGKILL: nothing ran to clean up) left its temporaries here.
        # Not per chunk (failures_file=False): each would scan the whole folder, and
        # clraster.distributed.render_views deletes them all once its tasks are done
        remove_temporaries(out)
    if isinstance(cameras, (str, os.PathLike)):
        from ..world.views import load_cameras

        cameras = load_cameras(cameras, strict=False, size=(renderer.width, renderer.height))
    cams = cameras if isinstance(cameras, Sequence) else list(cameras)
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
    for done, (k, item) in enumerate(frames(renderer, geometry, [t[1] for t in todo],
                                            render_kwargs), start=skipped + 1):
        _, _, key, old = todo[k]
        index = start + todo[k][0]
        if key is None or old != key:
            # files made with another camera or settings (or whose maker is unknown) are
            # not this view's: gone before anything is written, so that neither a failure
            # now nor a kill halfway leaves them looking done
            _marker(out, index).unlink(missing_ok=True)
            for p in view_files(out, index, tuple(OUTPUTS)).values():
                p.unlink(missing_ok=True)
        if isinstance(item, ViewError):
            # the engine numbers the views it was given; name the entry in the caller's list
            err = ViewError(index, item.field, item.message)
            failures.append(ViewFailure(index, str(err)))
            log.warning("%s", err)
        else:
            _write_view(view_files(out, index, outs), item, target)
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
