"""Command-line interface.

- ``clraster render MESH --size WxH --out image.png``: render one mesh (this module).
- ``clraster render MESH --views cameras.json --out DIR``: render one view per camera of a
  camera list file into DIR (`clraster.batch.render_views`; file format in `clraster.views`).
- ``clraster demo ...``: the built-in plant demo with the culling inspector
  (`clraster.demo.main`).
- ``clraster bench ...``: the benchmark harness (`clraster.bench.harness.main`; results and
  docs in the repository's ``bench/`` folder).

Exit codes: 0 success; 1 the mesh, camera or output could not be used, or memory ran out
(one line on stderr, no traceback), or with --views some views failed (a summary line on
stderr says how many and where their messages are); 2 bad command-line arguments
(argparse's usage message); 130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .camera import Camera
from .config import RasterConfig
from .device import NoDeviceError
from .inputs import parse_size
from .mesh import Mesh

if TYPE_CHECKING:
    from .frame import Frame

__all__ = ["main"]

EXAMPLE = "example"


def _vec3(text: str) -> np.ndarray:
    try:
        v = np.array([float(t) for t in text.split(",")])
    except ValueError:
        v = np.array([])
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise argparse.ArgumentTypeError(
            f"expected three finite numbers x,y,z, e.g. 0,1.5,4, got {text!r} "
            f"(write --eye=-1,2,3 when the first one is negative)")
    return v


def _output_file(path: Path, option: str, suffixes: tuple[str, ...] | None = None) -> None:
    """Refuse an output path before rendering (not after): a folder, a missing folder, no
    or the wrong suffix."""
    if path.is_dir():
        raise ValueError(f"{option} {str(path)!r} is a folder; give a file name")
    if not path.parent.is_dir():
        raise ValueError(f"{option} {str(path)!r}: folder {str(path.parent)!r} does not exist")
    suffix = path.suffix.lower()
    if suffixes is None:
        if not suffix:
            raise ValueError(f"{option} {str(path)!r} has no file extension; give one that "
                             f"names the image format, e.g. .png")
    elif suffix not in suffixes:
        raise ValueError(f"{option} {str(path)!r} must end in {' or '.join(suffixes)} "
                         f"(it is written as a NumPy array file)")


def _save_npy(path: Path, array: np.ndarray) -> None:
    # through a file object: np.save(name) would append .npy to any other name, so the
    # file written would not be the one reported
    with open(path, "wb") as fh:
        np.save(fh, array)


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not (np.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return v


def _outputs(text: str) -> tuple[str, ...]:
    from .batch import check_outputs

    try:
        return check_outputs(tuple(t.strip() for t in text.split(",") if t.strip()))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


#: single-view options that mean nothing with --views (dest → option)
_SINGLE_VIEW = {"eye": "--eye", "target": "--target", "near": "--near", "far": "--far",
                "depth": "--depth", "ids": "--ids", "wireframe": "--wireframe",
                "reference": "--reference"}


def _render_views(args: argparse.Namespace) -> int:
    from .batch import render_views
    from .renderer import Renderer

    if args.out.exists() and not args.out.is_dir():
        raise ValueError(f"--out {str(args.out)!r} is a file; with --views give a folder")
    if args.mesh == EXAMPLE:
        from .examples import example_mesh

        mesh = example_mesh()
    else:
        mesh = Mesh.load(args.mesh)
    width, height = args.size
    print(f"mesh: {args.mesh} ({mesh.n_vertices:,} vertices, {mesh.n_faces:,} triangles)")
    renderer = Renderer(width, height, config=RasterConfig(tile_log2=args.tile_log2))
    summary = render_views(mesh, args.views, args.out, args.outputs, renderer=renderer,
                           progress=True if args.progress else None, cull=args.cull)
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
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (_module, text) in DELEGATED.items():
        # listed for --help only: main() hands these to their modules before parsing
        sub.add_parser(name, help=text, add_help=False)
    r = sub.add_parser(
        "render", help="render a mesh to a shaded PNG (and optionally depth / ids)",
        description="Render MESH and write a flat-shaded image. Without --eye/--target the "
                    "camera frames the mesh's bounding box.")
    r.add_argument("mesh", metavar="MESH",
                   help=f"mesh file trimesh can read (PLY, OBJ, STL, ...), or "
                        f"'{EXAMPLE}' for the built-in example scene")
    r.add_argument("--size", type=parse_size, default=(1280, 720), metavar="WxH",
                   help="image size in pixels (default 1280x720)")
    r.add_argument("--out", type=Path, required=True, metavar="PNG",
                   help="shaded image to write (any format imageio writes); with --views, "
                        "the folder the views' files go to (created if missing)")
    many = r.add_argument_group(
        "many views", "--views renders one file set per camera of a JSON camera list "
                      "(look-at or matrices entries; see clraster.views) into the --out "
                      "folder: view_00000_depth.npy, view_00000_ids.npy, ... A re-run skips "
                      "views whose files all exist; a broken camera fails only its view.")
    many.add_argument("--views", type=Path, metavar="JSON",
                      help="camera list file; --out is then a folder")
    many.add_argument("--outputs", type=_outputs, default=("depth", "ids"),
                      metavar="LIST", help="comma-separated outputs per view out of depth, "
                                           "ids, bary, shaded (default depth,ids)")
    many.add_argument("--progress", action="store_true",
                      help="show a progress bar on stderr even when it is not a terminal")
    cam = r.add_argument_group(
        "camera", "OpenGL conventions: right-handed world, the camera looks from EYE "
                  "towards TARGET (down its −Z). Vectors are x,y,z; write --eye=-1,2,3 "
                  "when the first number is negative.")
    cam.add_argument("--eye", type=_vec3, metavar="X,Y,Z",
                     help="camera position (default: framing the bounding box)")
    cam.add_argument("--target", type=_vec3, metavar="X,Y,Z",
                     help="point looked at (default: bounding-box centre)")
    cam.add_argument("--up", type=_vec3, default=np.array([0.0, 1.0, 0.0]), metavar="X,Y,Z",
                     help="up direction (default 0,1,0)")
    cam.add_argument("--fov", type=float, default=45.0, metavar="DEG",
                     help="vertical field of view in degrees (default 45)")
    cam.add_argument("--near", type=_positive, metavar="N",
                     help="near-plane distance (default: from the bounding sphere)")
    cam.add_argument("--far", type=_positive, metavar="F",
                     help="far-plane distance (default: from the bounding sphere)")
    r.add_argument("--cull", choices=("back", "front", "none"), default="back",
                   help="face culling; counter-clockwise is front (default back)")
    r.add_argument("--depth", type=Path, metavar="NPY",
                   help="also save the (H, W) float32 window depth to this .npy file")
    r.add_argument("--ids", type=Path, metavar="NPY",
                   help="also save the (H, W) int32 triangle ids (-1 background) to this .npy "
                        "file")
    r.add_argument("--wireframe", action="store_true",
                   help="draw the mesh's edges over the image (line segments, clipped in clip "
                        "space and depth-tested against the frame, so hidden edges stay hidden)")
    r.add_argument("--wireframe-bias", type=float, default=1e-4, metavar="D",
                   help="window-depth bias of the wireframe's depth test (default 1e-4): an "
                        "edge shows where its depth <= surface depth + D")
    r.add_argument("--tile-log2", type=int, choices=range(3, 7), default=4, metavar="{3..6}",
                   help="tiles are 2**N pixels square (default 4); never changes the image")
    r.add_argument("--reference", action="store_true",
                   help="render with the NumPy reference pipeline instead of OpenCL")
    r.add_argument("--repeat", type=int, default=1, metavar="N",
                   help="render N times and report the first and the best frame time")
    return p


def _camera(args: argparse.Namespace, mesh: Mesh, width: int, height: int) -> Camera:
    """The camera the arguments describe; missing parts are fitted to the mesh bounds."""
    try:
        lo, hi = mesh.bounds()
    except ValueError:
        if args.eye is None or args.target is None:
            raise ValueError("the mesh has no finite vertex in a face, so the camera cannot "
                             "frame it; give --eye and --target") from None
        lo = hi = None
    if lo is not None:
        centre = (lo + hi) / 2.0
        radius = float(np.linalg.norm(hi - lo)) / 2.0
        framed = Camera.framing(lo, hi, fov_y=args.fov, aspect=width / height)
        eye = framed.eye if args.eye is None else args.eye
        target = centre if args.target is None else args.target
        if args.eye is None and args.target is None:
            near, far = framed.near, framed.far
        else:  # bracket the bounding sphere as seen from the eye
            dist = float(np.linalg.norm(eye - centre))
            far = (dist + radius) * 1.5 if radius > 0 else framed.far
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

    from .shade import shade

    width, height = args.size
    _output_file(args.out, "--out")
    for option, path in (("--depth", args.depth), ("--ids", args.ids)):
        if path is not None:
            _output_file(path, option, (".npy",))
    if args.mesh == EXAMPLE:
        from .examples import example_mesh

        mesh = example_mesh()
    else:
        mesh = Mesh.load(args.mesh)
    print(f"mesh: {args.mesh} ({mesh.n_vertices:,} vertices, {mesh.n_faces:,} triangles)")
    camera = _camera(args, mesh, width, height)
    print(f"camera: {camera!r}")

    if args.reference:
        from .reference import render as reference_render

        print("pipeline: NumPy reference")

        def draw() -> Frame:
            return reference_render(mesh, camera, width, height, cull=args.cull)
    else:
        from .renderer import Renderer

        renderer = Renderer(width, height, config=RasterConfig(tile_log2=args.tile_log2))
        print(f"device: {renderer.context.devices[0].name.strip()}")

        def draw() -> Frame:
            return renderer.render(mesh, camera, cull=args.cull)

    times = []
    frame = None
    for _ in range(max(1, args.repeat)):
        t0 = time.perf_counter()
        frame = draw()
        times.append((time.perf_counter() - t0) * 1e3)
    assert frame is not None

    image = shade(frame, mesh)
    if args.wireframe:
        from .lines import mesh_edges, overlay
        from .lines import render_lines as draw_lines
        from .reference.lines import render_lines as reference_lines

        edges = mesh_edges(mesh)
        draw = reference_lines if args.reference else draw_lines
        lines = draw(edges, camera, width, height, depth=frame.depth,
                     depth_bias=args.wireframe_bias)
        image = overlay(image, lines, (20, 20, 20))
        print(f"wireframe: {len(edges):,} edges, {int(lines.mask.sum()):,} pixels drawn")
    iio.imwrite(args.out, image)
    if args.depth is not None:
        _save_npy(args.depth, frame.depth)
    if args.ids is not None:
        _save_npy(args.ids, frame.triangle_id)

    print(frame.stats)
    line = f"frame time: {times[0]:.1f} ms (first frame"
    line += ", includes kernel build)" if not args.reference else ")"
    if len(times) > 1:
        line += f"; best of {len(times)}: {min(times):.1f} ms"
    print(line)
    written = [args.out] + [p for p in (args.depth, args.ids) if p is not None]
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


#: Subcommands that own their arguments: ``clraster NAME ARGS...`` calls ``main(ARGS)`` of
#: the module (each parses its own options and returns an exit code).
DELEGATED = {
    "demo": ("clraster.demo", "render the built-in plant: shaded, depth, overdraw and a "
                              "culling inspector"),
    "bench": ("clraster.bench.harness", "benchmark harness: OpenCL vs the NumPy twin and "
                                        "Mesa llvmpipe"),
}


def _delegate(name: str, argv: list[str]) -> int:
    import importlib

    module = importlib.import_module(DELEGATED[name][0])
    return int(module.main(argv) or 0)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI with `argv` (default ``sys.argv[1:]``); returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in DELEGATED:
        return _delegate(argv[0], argv[1:])
    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return int(exc.code or 0)
    if args.repeat < 1:
        parser.print_usage(sys.stderr)
        print(f"clraster: error: --repeat must be >= 1, got {args.repeat}", file=sys.stderr)
        return 2
    if args.views is not None:
        given = [opt for dest, opt in _SINGLE_VIEW.items()
                 if getattr(args, dest) is not None and getattr(args, dest) is not False]
        if given or args.repeat != 1:
            parser.print_usage(sys.stderr)
            print(f"clraster: error: {', '.join(given or ['--repeat'])} cannot be used with "
                  f"--views (the cameras come from the file, the outputs from --outputs)",
                  file=sys.stderr)
            return 2
        return run_guarded("clraster", lambda: _render_views(args))
    if args.progress or args.outputs != ("depth", "ids"):
        parser.print_usage(sys.stderr)
        print("clraster: error: --outputs and --progress need --views (one image: --out, "
              "--depth, --ids)", file=sys.stderr)
        return 2
    return run_guarded("clraster", lambda: _render(args))


def run_guarded(prog: str, command: Callable[[], int]) -> int:
    """Run a command's body; the errors a user can cause or fix become one line on stderr
    and an exit code (see the module docstring), never a traceback."""
    from .device import ForkedProcessError, device_busy

    try:
        return command()
    except (ValueError, OSError, NoDeviceError, ForkedProcessError) as exc:
        # Bad mesh, camera, output path or no OpenCL device: a message, not a traceback.
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    except MemoryError as exc:
        print(f"{prog}: error: out of memory ({exc or 'host memory'}); render a smaller "
              f"image (--size) or a smaller scene", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        if device_busy():
            # a kernel cannot be cancelled: rather than wait for it (seconds) or tear the
            # interpreter down under it, leave now
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(130)
        return 130


if __name__ == "__main__":
    sys.exit(main())
