"""Command-line interface.

- ``clraster render MESH --size WxH --out image.png``: render one mesh (this module).
- ``clraster render MESH --views cameras.json --out DIR``: render one view per camera of a
  camera list file into DIR (`clraster.batch.render_views`; file format in `clraster.views`);
  with ``--workers N`` on a local Dask cluster of N worker processes, with ``--scheduler
  ADDRESS`` on a running Dask cluster (`clraster.distributed.render_views`, same files).
- ``clraster demo ...``: the built-in plant demo with the culling inspector
  (`clraster.demo.main`).
- ``clraster view TARGET``: walk through a scene in a web browser
  (`clraster.viewer.command.main`).
- ``clraster devices``: list the OpenCL devices, whether each compiles clraster's probe
  kernel, and which one clraster would use and why (`clraster.pipeline.device`).
- ``clraster bench ...``: the benchmark harness (`clraster.bench.harness.main`; results and
  docs in the repository's ``bench/`` folder).

Exit codes: 0 success; 1 the mesh, camera or output could not be used, or memory ran out
(one line on stderr, no traceback), or nothing is visible in the image (a warning on stderr,
no file written; ``--allow-empty`` writes the empty image and exits 0), or with --views some
views failed (a summary line on stderr says how many and where their messages are); 2 bad
command-line arguments (argparse's usage message); 130 interrupted (Ctrl-C).

Output paths are checked before the mesh is loaded: two options naming one file (after
resolving ``./``, ``..``, links and hard links), a name longer than the file system allows,
a missing or read-only folder, a folder where a file is expected, are refused (exit 1). The
files of one image are then written all or none (`_write_all`).

Vectors (``--eye``, ``--target``, ``--up``) are three numbers, ``--eye 1 -2 3``; the older
one-word form ``--eye 1,-2,3`` (or ``--eye=-1,2,3``) is accepted too. A user clip plane
(``--clip-plane A B C D``, repeatable up to 8 times) is four numbers the same way.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import secrets
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from . import __version__
from .base.checks import parse_positive_int, parse_size
from .base.config import RasterConfig
from .cmdline import check_output_file, check_output_folder, run_guarded
from .world.camera import Camera
from .world.mesh import Mesh

if TYPE_CHECKING:
    from .output.frame import Frame

__all__ = ["main"]

EXAMPLE = "example"


#: options that take a vector of numbers → how many
_VECTOR_OPTIONS = {"--eye": 3, "--target": 3, "--up": 3, "--clip-plane": 4}


def _vec3(text: str) -> np.ndarray:
    try:
        v = np.array([float(t) for t in text.split(",")])
    except ValueError:
        v = np.array([])
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        shown = text.replace(",", " ")
        raise argparse.ArgumentTypeError(
            f"expected three finite numbers X Y Z, e.g. 0 -1.5 4, got {shown!r}")
    return v


def _plane(text: str) -> np.ndarray:
    """``--clip-plane``: four finite numbers A B C D with a non-zero normal (A, B, C)."""
    try:
        v = np.array([float(t) for t in text.split(",")])
    except ValueError:
        v = np.array([])
    shown = text.replace(",", " ")
    if v.shape != (4,) or not np.all(np.isfinite(v)):
        raise argparse.ArgumentTypeError(
            f"expected four finite numbers A B C D (keeping A*x + B*y + C*z + D >= 0), e.g. "
            f"0 -1 0 2.5, got {shown!r}")
    if not np.any(v[:3] != 0.0):
        raise argparse.ArgumentTypeError(
            f"the plane's normal A B C is zero ({shown!r}): it would keep everything or "
            f"nothing")
    return v


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _join_vectors(argv: list[str]) -> list[str]:
    """``--eye X Y Z`` (three words, negatives included) and ``--eye X,Y,Z`` as the one
    word ``--eye=X,Y,Z`` that `_vec3` parses (``--clip-plane A B C D`` likewise, four words
    for `_plane`). Done before argparse, which would read a word such as ``-1e-3`` or
    ``-1,2,3`` as an unknown option, not as a value."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        if tok == "--":
            out.extend(argv[i:])
            break
        i += 1
        if tok not in _VECTOR_OPTIONS or i >= len(argv):
            out.append(tok)
            continue
        if "," in argv[i]:
            out.append(f"{tok}={argv[i]}")
            i += 1
            continue
        words: list[str] = []
        while i < len(argv) and len(words) < _VECTOR_OPTIONS[tok] and _is_number(argv[i]):
            words.append(argv[i])
            i += 1
        # fewer numbers than the option takes: _vec3 (_plane) says what was expected
        out.append(f"{tok}={','.join(words)}" if words else tok)
    return out


def _distinct_outputs(outputs: Sequence[tuple[str, Path]]) -> None:
    """Refuse two options naming one file (one would silently overwrite the other): the
    same path after resolving ``.``/``..``, the current folder and links, or, for files
    that exist, two hard links to one file (`os.path.samefile`)."""
    seen: list[tuple[str, Path, str]] = []
    for option, path in outputs:
        real = os.path.normcase(os.path.realpath(path))
        for other_option, other, other_real in seen:
            same = real == other_real
            if not same:
                with contextlib.suppress(OSError):   # either missing: not a hard link
                    same = os.path.samefile(path, other)
            if same:
                raise ValueError(f"{other_option} {str(other)!r} and {option} {str(path)!r} "
                                 f"are the same file, so one would overwrite the other; give "
                                 f"each output its own file")
        seen.append((option, path, real))


def _write_all(writes: Sequence[tuple[Path, Callable[[Path], object]]]) -> None:
    """Write every output or none. Each ``write(tmp)`` writes a temporary file beside its
    output (the same folder, so that the rename is atomic; the output's extension, which
    names the format), and only when all are written are they renamed onto the outputs
    (where a link points, so a link stays a link). A failure on the way (an EXR without a
    plugin, ids beyond a 16-bit PNG, a full disk) leaves every output as it was and no
    temporary file behind. The temporary names are short, so an output name as long as
    the file system allows works."""
    staged: list[tuple[Path, Path]] = []
    try:
        for path, write in writes:
            target = Path(os.path.realpath(path))
            tmp = _temporary_beside(target, path.suffix)
            staged.append((tmp, target))
            write(tmp)
        for tmp, target in staged:
            os.replace(tmp, target)
    except BaseException:
        for tmp, _ in staged:
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise


def _temporary_beside(target: Path, suffix: str) -> Path:
    """A new empty file ``.clraster-<random>.part<suffix>`` in `target`'s folder (made
    with the umask's permissions, as the output would be)."""
    while True:
        tmp = target.parent / f".clraster-{secrets.token_hex(6)}.part{suffix}"
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            continue
        return tmp


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not (np.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return v


def _outputs(text: str) -> tuple[str, ...]:
    from .scale.batch import check_outputs

    try:
        return check_outputs(tuple(t.strip() for t in text.split(",") if t.strip()))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


#: image size of `clraster render` when neither --size nor a camera file gives one
_DEFAULT_SIZE = (1280, 720)

#: single-view options that mean nothing with --views (dest → option)
_SINGLE_VIEW = {"eye": "--eye", "target": "--target", "depth": "--depth", "ids": "--ids",
                "wireframe": "--wireframe", "reference": "--reference",
                "allow_empty": "--allow-empty"}


def _dask_client(args: argparse.Namespace, stack: contextlib.ExitStack):
    """A Dask client for --workers N (a LocalCluster of N worker processes, PoCL threads
    per worker = cores // N: `clraster.distributed.local_cluster`) or --scheduler ADDRESS;
    closed with ``stack``."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise ValueError("--workers and --scheduler need Dask: pip install "
                         "'clraster[distributed]'") from None
    if args.scheduler is not None:
        client = stack.enter_context(Client(args.scheduler))
        print(f"cluster: scheduler {args.scheduler}, {len(client.nthreads())} workers")
        return client
    from .scale.distributed import local_cluster

    cluster = stack.enter_context(local_cluster(args.workers))
    print(f"cluster: local, {args.workers} worker processes")
    return stack.enter_context(Client(cluster))


def _view_cameras(args: argparse.Namespace) -> tuple[list, tuple[int, int]]:
    """The cameras of --views and the size to render them at: the cameras' own (a COLMAP,
    NeRF or intrinsics file), which --size may repeat but not contradict; else --size, else
    1280x720."""
    from .world.camera_files import common_size
    from .world.views import load_cameras

    cameras = load_cameras(args.views, strict=False, size=args.size, near=args.near,
                           far=args.far, drop_distortion=args.drop_distortion)
    own = common_size(cameras)
    if own is not None and args.size is not None and own != tuple(args.size):
        raise ValueError(f"--size {args.size[0]}x{args.size[1]} differs from the "
                         f"{own[0]}x{own[1]} images of the cameras in {args.views}; leave "
                         f"--size out to render at theirs")
    return cameras, own or args.size or _DEFAULT_SIZE


def _render_views(args: argparse.Namespace) -> int:
    from .pipeline.renderer import Renderer
    from .scale.batch import check_output_depth_scale, check_writable_outputs, render_views

    # the outputs' formats and --depth-scale, before the mesh is loaded
    check_output_depth_scale(args.outputs, args.depth_scale)
    check_writable_outputs(args.outputs)

    if args.scheduler is None:
        check_output_folder(args.out, "--out")
    elif args.out.exists() and not args.out.is_dir():
        # a remote cluster's workers see --out; this host may not, so check no more here
        raise ValueError(f"--out {str(args.out)!r} is a file; with --views give a folder")
    if args.mesh == EXAMPLE:
        from .world.examples import example_mesh

        mesh = example_mesh()
    else:
        mesh = Mesh.load(args.mesh)
    cameras, (width, height) = _view_cameras(args)
    print(f"mesh: {args.mesh} ({mesh.n_vertices:,} vertices, {mesh.n_faces:,} triangles)")
    print(f"cameras: {len(cameras):,} from {args.views}, {width}x{height}")
    config = RasterConfig(tile_log2=args.tile_log2)
    summary: Any   # a Dask ViewsSummary or a RenderSummary: both have .failures
    if args.workers is not None or args.scheduler is not None:
        from .scale.distributed import render_views as dask_render_views

        with contextlib.ExitStack() as stack:
            client = _dask_client(args, stack)
            summary = dask_render_views(mesh, cameras, client, args.out, args.outputs,
                                        chunk=args.chunk, size=(width, height), config=config,
                                        progress=True if args.progress else None,
                                        overwrite=args.overwrite,
                                        depth_scale=args.depth_scale, cull=args.cull,
                                        reversed_z=args.reversed_z,
                                        clip_planes=args.clip_planes)
        print(summary)
        print(f"wrote {', '.join(args.outputs)} per view to {args.out}")
    else:
        renderer = Renderer(width, height, config=config)
        summary = render_views(mesh, cameras, args.out, args.outputs, renderer=renderer,
                               progress=True if args.progress else None,
                               overwrite=args.overwrite, depth_scale=args.depth_scale,
                               cull=args.cull,
                               reversed_z=args.reversed_z, clip_planes=args.clip_planes)
        print(f"{summary}; wrote {', '.join(args.outputs)} per view to {args.out}")
    if summary.failures:
        for f in summary.failures:
            print(f"clraster: view failed: {f.message}", file=sys.stderr)
        print(f"clraster: {len(summary.failures)} of {summary.views} views failed; messages "
              f"above and in {summary.failures_file}", file=sys.stderr)
        return 1
    return 0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="clraster", description="Tile-based software rasterizer on CPU OpenCL (PoCL).")
    p.add_argument("--version", action="version", version=f"clraster {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (_module, text) in DELEGATED.items():
        # listed for --help only: main() hands these to their modules before parsing
        sub.add_parser(name, help=text, add_help=False)
    # listed for --help only: main() runs it before parsing (`_devices`)
    sub.add_parser("devices", help="list the OpenCL devices and the one clraster would use",
                   add_help=False)
    r = sub.add_parser(
        "render", help="render a mesh to a shaded PNG (and optionally depth / ids)",
        description="Render MESH and write a flat-shaded image. Without --eye/--target the "
                    "camera frames the mesh's bounding box.")
    r.add_argument("mesh", metavar="MESH",
                   help=f"mesh file trimesh can read (PLY, OBJ, STL, ...), or "
                        f"'{EXAMPLE}' for the built-in example scene")
    r.add_argument("--size", type=parse_size, metavar="WxH",
                   help="image size in pixels (default 1280x720; with --views, the camera "
                        "file's own size where it has one)")
    r.add_argument("--out", type=Path, required=True, metavar="PNG",
                   help="shaded image to write (any format imageio writes); with --views, "
                        "the folder the views' files go to (created if missing)")
    many = r.add_argument_group(
        "many views", "--views renders one file set per camera of a JSON camera list "
                      "(look-at or matrices entries; see clraster.views) into the --out "
                      "folder: view_00000_depth.npy, view_00000_ids.npy, ... A re-run skips "
                      "views whose files all exist; a broken camera fails only its view.")
    many.add_argument("--views", type=Path, metavar="FILE",
                      help="camera file: a JSON camera list (look-at, matrices or K + pose "
                           "entries), a COLMAP text model folder, a NeRF transforms.json or "
                           "an .npz of K and poses; --out is then a folder")
    many.add_argument("--drop-distortion", action="store_true",
                      help="render the pinhole part of COLMAP / NeRF cameras with lens "
                           "distortion (refused otherwise)")
    many.add_argument("--overwrite", action="store_true",
                      help="re-render views whose files were made with other settings "
                           "(size, cull, clip planes...) instead of refusing the folder")
    many.add_argument("--outputs", type=_outputs, default=("depth", "ids"),
                      metavar="LIST",
                      help="comma-separated outputs per view, each NAME or NAME:FORMAT, out "
                           "of depth, ids, bary, shaded, linear_depth, distance, normals, "
                           "smooth_normals, camera_normals, smooth_camera_normals, mask, "
                           "points; formats png, tif, tiff, exr, npy, npz, ply (defaults: "
                           "npy; shaded, mask, linear_depth, distance png (16-bit, "
                           "--depth-scale); points ply with normals). Default depth,ids. "
                           "E.g. linear_depth:png,normals:npy,mask:png,ids:npy,points:ply")
    many.add_argument("--depth-scale", type=_positive, metavar="S",
                      help="linear_depth / distance PNGs hold round(depth * S), 0 = no hit "
                           "(default 1000: millimetres for a scene in metres); a view whose "
                           "depth does not fit 16 bits fails with its depth range")
    many.add_argument("--progress", action="store_true",
                      help="show a progress bar on stderr even when it is not a terminal "
                           "(with --workers/--scheduler: Dask's, on stdout)")
    where = many.add_mutually_exclusive_group()
    where.add_argument("--workers", type=parse_positive_int, metavar="N",
                       help="render on a local Dask cluster of N worker processes (PoCL "
                            "threads per worker = cores // N); each writes its views' files")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="render on a running Dask cluster (e.g. tcp://host:8786); --out "
                            "must be a folder every worker sees under the same path")
    many.add_argument("--chunk", type=parse_positive_int, metavar="N",
                      help="with --workers/--scheduler: cameras per Dask task (default up to "
                           "16, fewer for short lists)")
    cam = r.add_argument_group(
        "camera", "OpenGL conventions: right-handed world, the camera looks from EYE "
                  "towards TARGET (down its −Z). Vectors are three numbers, negatives "
                  "allowed: --eye 1 -2 3 (the form --eye 1,-2,3 works too).")
    cam.add_argument("--eye", type=_vec3, metavar="X Y Z",
                     help="camera position (default: framing the bounding box)")
    cam.add_argument("--target", type=_vec3, metavar="X Y Z",
                     help="point looked at (default: bounding-box centre)")
    cam.add_argument("--up", type=_vec3, default=np.array([0.0, 1.0, 0.0]), metavar="X Y Z",
                     help="up direction (default 0 1 0)")
    cam.add_argument("--fov", type=float, default=45.0, metavar="DEG",
                     help="vertical field of view in degrees (default 45)")
    cam.add_argument("--near", type=_positive, metavar="N",
                     help="near-plane distance (default: from the bounding sphere; with "
                          "--views, for COLMAP / NeRF / .npz cameras, which carry none)")
    cam.add_argument("--far", type=_positive, metavar="F",
                     help="far-plane distance (default: from the bounding sphere; with "
                          "--views, as --near)")
    r.add_argument("--cull", choices=("back", "front", "none"), default="back",
                   help="face culling; counter-clockwise is front (default back)")
    r.add_argument("--depth", type=Path, metavar="FILE",
                   help="also save the (H, W) window depth (1.0 background); the extension "
                        "names the format: .npy/.npz/.tif float32, .png 16-bit (see "
                        "clraster.outputs)")
    r.add_argument("--reversed-z", action="store_true",
                   help="depth as reversed-Z, (1 - z/w)/2: 1 at the near plane, 0 at the far "
                        "plane and on the background; float32 keeps far depths distinct "
                        "(the depth test uses it too)")
    r.add_argument("--clip-plane", type=_plane, action="append", metavar="A B C D",
                   help="user clip plane in world space: keep the points with a*x + b*y + "
                        "c*z + d >= 0 (as OpenGL's gl_ClipDistance; points on the plane are "
                        "kept); repeat for up to 8 planes, a point must be kept by all. The "
                        "wireframe is clipped too")
    r.add_argument("--ids", type=Path, metavar="FILE",
                   help="also save the (H, W) triangle ids: .npy/.npz/.tif int32 (-1 "
                        "background), .png uint16 id + 1 (0 background)")
    r.add_argument("--wireframe", action="store_true",
                   help="draw the mesh's edges over the image (line segments, clipped in clip "
                        "space and depth-tested against the frame, so hidden edges stay hidden)")
    r.add_argument("--wireframe-bias", type=float, default=1e-4, metavar="D",
                   help="window-depth bias of the wireframe's depth test (default 1e-4): an "
                        "edge shows where its depth <= surface depth + D")
    r.add_argument("--tile-log2", type=int, choices=range(3, 7),
                   default=RasterConfig().tile_log2, metavar="{3..6}",
                   help="tiles are 2**N pixels square (default: RasterConfig's, "
                        f"{RasterConfig().tile_log2}); never changes the image")
    r.add_argument("--reference", action="store_true",
                   help="render with the NumPy reference pipeline instead of OpenCL")
    r.add_argument("--repeat", type=int, default=1, metavar="N",
                   help="render N times and report the first and the best frame time")
    r.add_argument("-q", "--quiet", action="store_true",
                   help="one image: print nothing but warnings and errors (no mesh, camera "
                        "and device lines, no stage table, no frame time)")
    r.add_argument("--allow-empty", action="store_true",
                   help="write the files even when nothing is visible (by default an empty "
                        "view is a warning and exit 1, with no file written)")
    return p


def _camera(args: argparse.Namespace, mesh: Mesh, width: int, height: int) -> Camera:
    """The camera the arguments describe; missing parts are fitted to the mesh bounds."""
    lo: np.ndarray | None
    hi: np.ndarray | None
    near: float
    far: float
    try:
        lo, hi = mesh.bounds()
    except ValueError:
        if args.eye is None or args.target is None:
            raise ValueError("the mesh has no finite vertex in a face, so the camera cannot "
                             "frame it; give --eye and --target") from None
        lo = hi = None
    if lo is not None and hi is not None:   # both or neither
        centre = (lo + hi) / 2.0
        radius = float(np.linalg.norm(hi - lo)) / 2.0
        framed = Camera.framing(lo, hi, fov_y=args.fov, aspect=width / height)
        eye = framed.eye if args.eye is None else args.eye
        target = centre if args.target is None else args.target
        if args.eye is None and args.target is None:
            near, far = cast(float, framed.near), cast(float, framed.far)
        else:  # bracket the bounding sphere as seen from the eye
            dist = float(np.linalg.norm(eye - centre))
            far = (dist + radius) * 1.5 if radius > 0 else cast(float, framed.far)
            near = (dist - radius) * 0.5 if dist > radius * 1.01 else far * 1e-4
    else:
        eye, target, near, far = args.eye, args.target, 0.1, 100.0
    near = args.near if args.near is not None else near
    far = args.far if args.far is not None else far
    if args.far is None and far <= near:
        far = near * 1e4
    return Camera.look_at(eye, target, args.up, fov_y=args.fov, near=near, far=far)


def _render(args: argparse.Namespace) -> int:
    import imageio.v3 as iio

    from .output.outputs import check_output_path, write_output
    from .output.shade import shade

    width, height = args.size or _DEFAULT_SIZE
    # --quiet: nothing on stdout; warnings and errors still go to stderr
    info: Callable[..., None] = _silent if args.quiet else print
    check_output_file(args.out, "--out")
    for option, path, what in (("--depth", args.depth, "depth"), ("--ids", args.ids, "ids")):
        if path is not None:
            check_output_file(path, option, ())
            try:   # the extension names the format (clraster.outputs): checked up front
                check_output_path(path, what)
            except ValueError as exc:
                raise ValueError(f"{option}: {exc}") from None
    _distinct_outputs([(option, path) for option, path in
                       (("--out", args.out), ("--depth", args.depth), ("--ids", args.ids))
                       if path is not None])
    if args.mesh == EXAMPLE:
        from .world.examples import example_mesh

        mesh = example_mesh()
    else:
        mesh = Mesh.load(args.mesh)
    info(f"mesh: {args.mesh} ({mesh.n_vertices:,} vertices, {mesh.n_faces:,} triangles)")
    camera = _camera(args, mesh, width, height)
    info(f"camera: {camera!r}")

    if args.reference:
        from .pipeline.reference import render as reference_render

        info("pipeline: NumPy reference")

        def draw() -> Frame:
            return reference_render(mesh, camera, width, height, cull=args.cull,
                                    reversed_z=args.reversed_z, clip_planes=args.clip_planes)
    else:
        from .pipeline.renderer import Renderer

        renderer = Renderer(width, height, config=RasterConfig(tile_log2=args.tile_log2))
        info(f"device: {renderer.context.devices[0].name.strip()}")

        def draw() -> Frame:
            return renderer.render(mesh, camera, cull=args.cull, reversed_z=args.reversed_z,
                                   clip_planes=args.clip_planes)

    times = []
    frame = None
    for _ in range(max(1, args.repeat)):
        t0 = time.perf_counter()
        frame = draw()
        times.append((time.perf_counter() - t0) * 1e3)
    assert frame is not None
    if not args.allow_empty and not np.any(frame.triangle_id >= 0):
        # a blank image with exit 0 looks like success to a script: say so, write nothing
        info(frame.stats)
        print(f"clraster: warning: nothing is visible ({_why_empty(frame)}); no file "
              f"written. Check the camera (--eye, --target, --near, --far) and --cull, or "
              f"pass --allow-empty to write the empty image", file=sys.stderr)
        return 1

    image = shade(frame, mesh)
    if args.wireframe:
        from .pipeline.lines import mesh_edges, overlay
        from .pipeline.lines import render_lines as draw_lines
        from .pipeline.reference.lines import render_lines as reference_lines

        edges = mesh_edges(mesh)
        draw_edges = reference_lines if args.reference else draw_lines
        lines = draw_edges(edges, camera, width, height, depth=frame.depth,
                           depth_bias=args.wireframe_bias, clip_planes=args.clip_planes)
        image = overlay(image, lines, (20, 20, 20))
        info(f"wireframe: {len(edges):,} edges, {int(lines.mask.sum()):,} pixels drawn")
    writes: list[tuple[Path, Callable[[Path], object]]] = [
        (args.out, lambda tmp: iio.imwrite(tmp, image))]
    if args.depth is not None:
        writes.append((args.depth, lambda tmp: write_output(tmp, frame, "depth")))
    if args.ids is not None:
        writes.append((args.ids, lambda tmp: write_output(tmp, frame, "ids")))
    _write_all(writes)   # all or none: no --out left behind by a failing --ids

    info(frame.stats)
    line = f"frame time: {times[0]:.1f} ms (first frame"
    line += ", includes kernel build)" if not args.reference else ")"
    if len(times) > 1:
        line += f"; best of {len(times)}: {min(times):.1f} ms"
    info(line)
    written = [args.out] + [p for p in (args.depth, args.ids) if p is not None]
    info("wrote " + ", ".join(str(p) for p in written))
    return 0


def _silent(*_args: object, **_kwargs: object) -> None:
    """`print` under --quiet."""


def _why_empty(frame: Frame) -> str:
    """Where an empty frame's triangles went, from its stats (one clause)."""
    st = frame.stats
    if st.triangles_total == 0:
        return "the mesh has no triangle"
    parts = [(st.triangles_frustum_culled + st.trivially_rejected, "outside the view"),
             (st.triangles_cone_culled + st.backface_culled, "facing away (--cull)"),
             (st.degenerate + st.no_sample, "too small to cover a pixel centre"),
             (st.invalid, "with a NaN/Inf vertex")]
    said = ", ".join(f"{n:,} {what}" for n, what in parts if n)
    return f"of {st.triangles_total:,} triangles: {said or 'none drew a pixel'}"


#: Subcommands that own their arguments: ``clraster NAME ARGS...`` calls ``main(ARGS)`` of
#: the module (each parses its own options and returns an exit code).
DELEGATED = {
    "demo": ("clraster.demo", "render the built-in plant: shaded, depth, overdraw and a "
                              "culling inspector"),
    "bench": ("clraster.bench.harness", "benchmark harness: OpenCL vs the NumPy twin and "
                                        "Mesa llvmpipe"),
    "view": ("clraster.viewer.command", "walk through a scene in a web browser (frames "
                                        "streamed from a local server)"),
}


def _delegate(name: str, argv: list[str]) -> int:
    import importlib

    module = importlib.import_module(DELEGATED[name][0])
    return int(module.main(argv) or 0)


def _devices(argv: list[str]) -> int:
    """``clraster devices``: every OpenCL device, whether it compiles the probe kernel, and
    the one a Renderer made now would use (CLRASTER_DEVICE > PYOPENCL_CTX > default)."""
    p = argparse.ArgumentParser(
        prog="clraster devices",
        description="List the OpenCL devices clraster can see and the one it would use. "
                    "Choose with CLRASTER_DEVICE (pocl, intel, oclgrind, or a part of a "
                    "platform or device name; case-insensitive) or Renderer(device=...); "
                    "precedence: device= > CLRASTER_DEVICE > PYOPENCL_CTX > default (the "
                    "first CPU device that compiles, PoCL first, never Oclgrind).")
    try:
        p.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)

    def body() -> int:
        from .pipeline.device import NoDeviceError, choose_context, describe_choice, list_devices
        from .pipeline.runtimes import wheel_runtimes

        rows = list_devices()
        print("OpenCL devices (* the one clraster uses):" if rows else "OpenCL devices: none")
        try:
            ctx, reason = choose_context()
        except NoDeviceError as exc:   # the table still helps choose; then the error
            ctx, reason, failure = None, "", exc
        for r in rows:
            state = "compiles" if r.compiles else f"does not compile: {r.compile_error}"
            if "oclgrind" in r.platform.lower():
                state += " (a simulator, ~1000x slower)"
            mark = "*" if ctx is not None and r.device == ctx.devices[0] else " "
            print(f"{mark} {r.label}  [{r.kind}; {r.platform_version}]  {state}")
        for rt in wheel_runtimes():   # installed from PyPI, yet not usable: say why
            if rt.installed and not rt.registered:
                print(f"  not listed: {rt.describe()}")
        if ctx is None:
            raise failure
        print(f"clraster uses: {describe_choice(ctx, reason)}")
        return 0

    return run_guarded("clraster devices", body)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI with `argv` (default ``sys.argv[1:]``); returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in DELEGATED:
        return _delegate(argv[0], argv[1:])
    if argv and argv[0] == "devices":
        return _devices(argv[1:])
    parser = _parser()
    if argv and argv[0] == "render":
        argv = _join_vectors(argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return int(exc.code or 0)
    if args.repeat < 1:
        parser.print_usage(sys.stderr)
        print(f"clraster: error: --repeat must be >= 1, got {args.repeat}", file=sys.stderr)
        return 2
    from .base.layout import USER_PLANES_MAX

    if args.clip_plane is not None and len(args.clip_plane) > USER_PLANES_MAX:
        parser.print_usage(sys.stderr)
        print(f"clraster: error: at most {USER_PLANES_MAX} --clip-plane options, got "
              f"{len(args.clip_plane)}", file=sys.stderr)
        return 2
    # (K, 4) float64 world planes for every render call, or None
    args.clip_planes = None if args.clip_plane is None else np.stack(args.clip_plane)
    if args.views is not None:
        given = [opt for dest, opt in _SINGLE_VIEW.items()
                 if getattr(args, dest) is not None and getattr(args, dest) is not False]
        if given or args.repeat != 1:
            parser.print_usage(sys.stderr)
            print(f"clraster: error: {', '.join(given or ['--repeat'])} cannot be used with "
                  f"--views (the cameras come from the file, the outputs from --outputs)",
                  file=sys.stderr)
            return 2
        if args.chunk is not None and args.workers is None and args.scheduler is None:
            parser.print_usage(sys.stderr)
            print("clraster: error: --chunk needs --workers or --scheduler (it sizes the Dask "
                  "tasks)", file=sys.stderr)
            return 2
        return run_guarded("clraster", lambda: _render_views(args))
    if (args.progress or args.outputs != ("depth", "ids") or args.workers is not None
            or args.scheduler is not None or args.chunk is not None or args.overwrite
            or args.drop_distortion or args.depth_scale is not None):
        parser.print_usage(sys.stderr)
        print("clraster: error: --outputs, --depth-scale, --progress, --workers, --scheduler, "
              "--chunk, --overwrite and --drop-distortion need --views (one image: --out, "
              "--depth, --ids)", file=sys.stderr)
        return 2
    return run_guarded("clraster", lambda: _render(args))


if __name__ == "__main__":
    sys.exit(main())
