"""Render many views of one scene to files: `render_views`.

One file set per view in ``out_dir``, named by the view's index in the camera list:
``view_00000_depth.npy`` (float32 (H, W) window depth, 1.0 background),
``view_00000_ids.npy`` (int32 (H, W) triangle ids, −1 background),
``view_00000_bary.npy`` (float32 (H, W, 3) barycentrics) and ``view_00000_shaded.png``
(flat-shaded RGB, `clraster.shade.shade`). Row 0 is the top row, as in
`clraster.Frame`. Each file is written to a temporary name in ``out_dir`` and renamed into
place (os.replace), so a file under its final name is always complete, and a batch killed
halfway leaves no half-written files under those names. A re-run skips the views whose
files all exist, which is what makes a batch resumable (and a Dask task retryable); give a
fresh ``out_dir`` when the cameras change.

A view whose camera is broken (a malformed entry, NaN, a singular matrix, near >= far, a
matrix that overflows float32) fails with a message naming its index and field; the rest
of the batch goes on, and the failures come back in the summary (and in
``out_dir/failures.json``).
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from .views import ViewError, check_render_kwargs, check_target, frames

if TYPE_CHECKING:
    from .frame import Frame
    from .renderer import Renderer

__all__ = ["OUTPUTS", "RenderSummary", "ViewFailure", "render_views", "view_files"]

log = logging.getLogger(__name__)

#: output name → file suffix
OUTPUTS = {"depth": ".npy", "ids": ".npy", "bary": ".npy", "shaded": ".png"}
#: where the failures of the last run are listed (absent when it had none)
FAILURES_FILE = "failures.json"


@dataclass(frozen=True)
class ViewFailure:
    """A view that was not rendered: its index in the camera list and why."""

    index: int
    message: str


@dataclass(frozen=True)
class RenderSummary:
    """What `render_views` did.

    views: views in the camera list. rendered: views rendered and written this run.
    skipped: views whose files all existed already. failures: the views that failed, in
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
    ``path`` (atomic on POSIX and Windows within one folder)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _write_view(files: dict[str, Path], frame: Frame, target: Any) -> None:
    arrays = {"depth": frame.depth, "ids": frame.triangle_id, "bary": frame.barycentrics}
    for name, path in files.items():
        if name == "shaded":
            from PIL import Image

            from .shade import shade

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
                 **render_kwargs: Any) -> RenderSummary:
    """Render ``target`` (a `clraster.Mesh` or `clraster.Scene`) from every camera and write
    one file set per view into ``out_dir`` (names and formats: the module docstring).

    Args:
        cameras: a list of cameras (`clraster.Camera`, camera entry dicts, objects with
            ``view_projection``) or the path of a camera list file (`clraster.views`).
        out_dir: created if missing (its parent must exist).
        outputs: any of "depth", "ids", "bary", "shaded".
        size: (width, height) of the images, when no ``renderer`` is given.
        renderer: a `clraster.Renderer` to render with (its size is used); default a new
            one of ``size``.
        start: index of ``cameras[0]`` in the whole list, for file names, when a list is
            split into chunks rendered apart (e.g. one Dask task per chunk).
        progress: a progress bar on stderr; default only when stderr is a terminal.
        failures_file: write (or remove) ``out_dir/failures.json``; False leaves it alone,
            for chunks of one list run side by side (`clraster.distributed.render_views`
            writes the merged list once).
        render_kwargs: `Renderer.render`'s keywords (cull, frustum, cones, occlusion, ...).

    Returns:
        a `RenderSummary` (views, rendered, skipped, failures, views/s).

    Raises:
        ValueError / TypeError: bad outputs, target or keywords (before anything is
            rendered); CameraFileError: a camera list file that is not a list of entries.
            Errors writing files (OSError) stop the batch.
    """
    from .renderer import Renderer

    outs = check_outputs(outputs)
    check_target(target)
    if isinstance(start, bool) or not isinstance(start, int) or start < 0:
        raise ValueError(f"start must be an integer >= 0, got {start!r}")
    if renderer is None:
        renderer = Renderer(*size)
    check_render_kwargs(renderer, render_kwargs)
    if "bary" not in outs and "shaded" not in outs and "outputs" not in render_kwargs:
        # no file needs the barycentrics: 8 bytes a pixel are made instead of 20
        render_kwargs = {**render_kwargs, "outputs": ("depth", "ids")}
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir {str(out)!r} exists and is not a folder")
    if not out.parent.is_dir():
        raise ValueError(f"out_dir {str(out)!r}: folder {str(out.parent)!r} does not exist")
    out.mkdir(exist_ok=True)
    if isinstance(cameras, (str, os.PathLike)):
        from .views import load_cameras

        cameras = load_cameras(cameras, strict=False)
    cams = cameras if isinstance(cameras, Sequence) else list(cameras)
    show = sys.stderr.isatty() if progress is None else bool(progress)
    bar = _Progress(sys.stderr, len(cams)) if show else None

    t0 = time.perf_counter()
    failures: list[ViewFailure] = []
    rendered = skipped = 0
    todo = []   # (index in the whole list, camera) of views whose files are not all there
    for k, cam in enumerate(cams):
        if all(p.exists() for p in view_files(out, start + k, outs).values()):
            skipped += 1
        else:
            todo.append((k, cam))
    for done, (k, item) in enumerate(frames(renderer, target, [c for _, c in todo],
                                            render_kwargs), start=skipped + 1):
        index = start + todo[k][0]
        if isinstance(item, ViewError):
            # the engine numbers the views it was given; name the entry in the caller's list
            err = ViewError(index, item.field, item.message)
            failures.append(ViewFailure(index, str(err)))
            log.warning("%s", err)
        else:
            _write_view(view_files(out, index, outs), item, target)
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
