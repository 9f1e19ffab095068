"""Users' camera files → `clraster.Camera` lists: COLMAP text models, NeRF / instant-ngp
``transforms.json``, and NumPy ``.npz`` arrays of K and poses.

Every reader returns one `Camera` per view, in the file's order, each made by
`Camera.from_intrinsics` and therefore tied to its image size (`Camera.image_size`);
`common_size` gives the one size a batch renders at. What each format means, from its own
documentation, and how it becomes OpenCV's K (pixel (i, j)'s centre at (u, v) = (i, j)):

==============  ===============================  ============================  ===============
format          pose                             camera axes                   pixel centres
==============  ===============================  ============================  ===============
COLMAP text     world → camera, quaternion       +x right, +y down, +z         (i + ½, j + ½):
                (QW QX QY QZ) and T (TX TY TZ)   forward (OpenCV)              cx − ½ in K
NeRF            camera → world                   +x right, +y up, looking      (i + ½, j + ½):
transforms      ``transform_matrix`` (4×4)       down −z (OpenGL/Blender)      cx − ½ in K
NPZ             camera → world ``poses``         ``convention``: opencv        (i, j): K as
                                                 (default) or opengl           given
==============  ===============================  ============================  ===============

COLMAP documents its image origin as the upper-left corner of the upper-left pixel, whose
centre is at (0.5, 0.5); nerfstudio and instant-ngp generate the ray of pixel (0, 0)
through its centre in the same corner-origin coordinates, and a ``transforms.json`` with
only ``camera_angle_x`` has its principal point at the image centre (w/2, h/2) in them.

None of these formats carries clip planes: the readers take ``near`` and ``far`` (the
distance range along the optical axis that can appear in the image, in the scene's units).

Lens distortion is not rendered (a rasterizer draws straight lines straight): COLMAP models
and NeRF files with non-zero distortion coefficients are refused, naming the model, unless
``drop_distortion=True`` asks to render the pinhole part alone. Fisheye models are refused
either way (their pinhole part is not an approximation of the lens).
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from .camera import CONVENTIONS, Camera

__all__ = ["CameraFileError", "common_size", "nerf_cameras", "read_colmap", "read_nerf",
           "read_npz"]


class CameraFileError(ValueError):
    """A camera file that cannot be read as cameras at all: the message names the file and,
    where there is one, the line, frame or array at fault. (Broken entries of a JSON camera
    list are `clraster.views.ViewError` instead.)"""


#: COLMAP camera models: parameter names in file order (colmap/src/colmap/sensor/models.h).
_COLMAP_MODELS: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
    "SIMPLE_RADIAL_FISHEYE": ("f", "cx", "cy", "k"),
    "RADIAL_FISHEYE": ("f", "cx", "cy", "k1", "k2"),
    "THIN_PRISM_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "sx1",
                           "sy1"),
    "FOV": ("fx", "fy", "cx", "cy", "omega"),
}
_FISHEYE = ("FISHEYE", "FOV")
#: NeRF / instant-ngp / nerfstudio distortion keys (transforms.json).
_NERF_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
#: transforms.json camera models with a pinhole projection (plus distortion coefficients)
_NERF_PINHOLE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")


def _clip_range(near: float | None, far: float | None, where: str) -> tuple[float, float]:
    if near is None or far is None:
        raise CameraFileError(f"{where} gives no clip planes: pass near= and far= (the range "
                              f"of distances along the optical axis to render, in the "
                              f"scene's units; CLI: --near and --far)")
    return float(near), float(far)


def _intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _make(k: np.ndarray, width: int, height: int, pose: np.ndarray, convention: str,
          near: float, far: float, where: str) -> Camera:
    try:
        return Camera.from_intrinsics(k, width, height, pose=pose, near=near, far=far,
                                      convention=convention)
    except ValueError as exc:
        raise CameraFileError(f"{where}: {exc}") from None


def _distortion(model: str, values: dict[str, float], drop: bool, where: str) -> None:
    """Refuse a lens the pinhole camera cannot render (module docstring)."""
    if any(s in model for s in _FISHEYE):
        raise CameraFileError(f"{where}: camera model {model} is a fisheye lens; clraster "
                              f"renders pinhole cameras only (undistort the images to a "
                              f"PINHOLE model first, e.g. colmap image_undistorter)")
    nonzero = {k: v for k, v in values.items() if v != 0.0}
    if nonzero and not drop:
        listed = ", ".join(f"{k}={v:g}" for k, v in nonzero.items())
        raise CameraFileError(f"{where}: camera model {model} has lens distortion ({listed}), "
                              f"which a rasterizer does not render; undistort the model "
                              f"(PINHOLE), or pass drop_distortion=True (CLI: "
                              f"--drop-distortion) to render its pinhole part alone")


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation of the unit quaternion (w, x, y, z), Hamilton convention as COLMAP's."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _numbers(fields: list[str], where: str) -> list[float]:
    try:
        out = [float(f) for f in fields]
    except ValueError:
        raise CameraFileError(f"{where}: expected numbers, got {' '.join(fields)!r:.120}"
                              ) from None
    if not all(math.isfinite(v) for v in out):
        raise CameraFileError(f"{where}: values must be finite, got {' '.join(fields):.120}")
    return out


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of a COLMAP text file, comments dropped, empty lines kept (an
    image without 2-D points has an empty POINTS2D line)."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise CameraFileError(f"{path}: not a UTF-8 text file ({exc.reason})") from None
    return [(n, s.strip()) for n, s in enumerate(text.splitlines(), 1)
            if not s.lstrip().startswith("#")]


def _colmap_folder(path: Path) -> Path:
    for cand in (path, path / "sparse" / "0", path / "sparse", path / "0"):
        if (cand / "cameras.txt").is_file() and (cand / "images.txt").is_file():
            return cand
    if (path / "cameras.bin").is_file() or (path / "sparse" / "0" / "cameras.bin").is_file():
        raise CameraFileError(f"{path}: a binary COLMAP model; convert it to text first "
                              f"(colmap model_converter --output_type TXT)")
    raise CameraFileError(f"{path}: no COLMAP text model here (cameras.txt and images.txt, "
                          f"also looked in sparse/0 and sparse)")


def read_colmap(path: str | os.PathLike, *, near: float | None = None,
                far: float | None = None, drop_distortion: bool = False
                ) -> tuple[list[Camera], list[str]]:
    """Cameras of a COLMAP text model: a folder with ``cameras.txt`` and ``images.txt`` (or
    ``sparse/0`` below it).

    Returns:
        (cameras, names): one `Camera` per image of ``images.txt`` in the file's order,
        tied to its camera's WIDTH × HEIGHT, and the images' NAMEs.

    Raises:
        CameraFileError: no model, a malformed line (named by file and line number), an
            image naming an unknown CAMERA_ID, a model with distortion (module docstring),
            no near/far.
    """
    folder = _colmap_folder(Path(path))
    near, far = _clip_range(near, far, f"{folder} (a COLMAP model)")
    cams: dict[int, tuple[str, int, int, dict[str, float]]] = {}
    cfile = folder / "cameras.txt"
    for n, line in _data_lines(cfile):
        if not line:
            continue
        f = line.split()
        where = f"{cfile}:{n}"
        if len(f) < 4:
            raise CameraFileError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        model = f[1]
        names = _COLMAP_MODELS.get(model)
        if names is None:
            raise CameraFileError(f"{where}: unknown camera model {model!r} (known: "
                                  f"{', '.join(_COLMAP_MODELS)})")
        if len(f) != 4 + len(names):
            raise CameraFileError(f"{where}: model {model} has {len(names)} parameters "
                                  f"({' '.join(names)}), got {len(f) - 4}")
        try:
            cam_id, width, height = int(f[0]), int(f[2]), int(f[3])
        except ValueError:
            raise CameraFileError(f"{where}: CAMERA_ID, WIDTH and HEIGHT must be integers"
                                  ) from None
        params = dict(zip(names, _numbers(f[4:], where), strict=True))
        pinhole = {"f", "fx", "fy", "cx", "cy"}
        _distortion(model, {k: v for k, v in params.items() if k not in pinhole},
                    drop_distortion, f"{where} (camera {cam_id})")
        cams[cam_id] = (model, width, height, params)
    ifile = folder / "images.txt"
    lines = _data_lines(ifile)
    cameras: list[Camera] = []
    image_names: list[str] = []
    i = 0
    while i < len(lines):
        n, line = lines[i]
        if not line:            # blank lines between images (or at the end)
            i += 1
            continue
        where = f"{ifile}:{n}"
        f = line.split(maxsplit=9)
        if len(f) < 10:
            raise CameraFileError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID "
                                  f"NAME")
        q = np.array(_numbers(f[1:5], where))
        t = np.array(_numbers(f[5:8], where))
        if not np.linalg.norm(q) > 0.0:
            raise CameraFileError(f"{where}: the quaternion QW QX QY QZ is zero")
        try:
            cam_id = int(f[8])
        except ValueError:
            raise CameraFileError(f"{where}: CAMERA_ID must be an integer, got {f[8]!r}"
                                  ) from None
        if cam_id not in cams:
            raise CameraFileError(f"{where}: CAMERA_ID {cam_id} is not in {cfile}")
        model, width, height, p = cams[cam_id]
        fx = p.get("fx", p.get("f"))
        fy = p.get("fy", p.get("f"))
        # COLMAP's pixel centres are at (i + 0.5, j + 0.5); OpenCV's K at (i, j)
        k = _intrinsics(float(fx), float(fy), p["cx"] - 0.5, p["cy"] - 0.5)  # type: ignore[arg-type]
        r = _quat_to_matrix(q)                      # world → camera
        pose = np.eye(4)
        pose[:3, :3] = r.T
        pose[:3, 3] = -r.T @ t
        cameras.append(_make(k, width, height, pose, "opencv", near, far,
                             f"{where} (image {f[9]!r}, camera {cam_id})"))
        image_names.append(f[9])
        # the POINTS2D line that follows: empty, absent at the end, or X Y POINT3D_ID triples.
        # Anything else is a file written one line per image, whose every other image would
        # otherwise be read as points and lost
        if i + 1 < len(lines):
            n2, pts = lines[i + 1]
            fields = pts.split()
            try:
                [float(x) for x in fields]
                ok = len(fields) % 3 == 0
            except ValueError:
                ok = False
            if not ok:
                raise CameraFileError(f"{ifile}:{n2}: expected the POINTS2D line of the image "
                                      f"on line {n} (X Y POINT3D_ID triples, or an empty "
                                      f"line); COLMAP writes two lines per image")
        i += 2
    if not cameras:
        raise CameraFileError(f"{ifile}: no images")
    return cameras, image_names


def _nerf_number(d: dict, key: str, where: str) -> float | None:
    v = d.get(key)
    if v is None:
        return None
    try:
        f = float(v) if not isinstance(v, bool) and isinstance(v, (int, float)) else math.nan
    except OverflowError:   # an integer beyond float64
        f = math.inf
    if not math.isfinite(f):
        raise CameraFileError(f"{where}: {key!r} must be a finite number, got {v!r:.60}")
    return f


def _pixels(v: float | None, key: str, where: str) -> int | None:
    """An image dimension: a positive whole number (never truncated)."""
    if v is None:
        return None
    if not (v > 0 and float(v).is_integer()):
        raise CameraFileError(f"{where}: {key!r} is an image size in pixels and must be a "
                              f"positive whole number, got {v:g}")
    return int(v)


def read_nerf(path: str | os.PathLike, *, width: int | None = None, height: int | None = None,
              near: float | None = None, far: float | None = None,
              drop_distortion: bool = False) -> tuple[list[Camera], list[str]]:
    """Cameras of a NeRF / instant-ngp / nerfstudio ``transforms.json``.

    Intrinsics at the top level or per frame (a frame's value wins): ``fl_x``/``fl_y``
    (pixels; ``fl_y`` defaults to ``fl_x``) or ``camera_angle_x`` (horizontal field of view
    in radians across the image width; ``camera_angle_y`` likewise, else square pixels),
    ``cx``/``cy`` (default w/2, h/2), ``w``/``h`` (pixels). Each frame's
    ``transform_matrix`` is its camera → world pose (4×4, or 3×4) in OpenGL axes.

    Args:
        width, height: the image size where the file gives none (the original Blender
            scenes); a file's own ``w``/``h`` that differ from them are an error.

    Returns:
        (cameras, names): one `Camera` per frame, and each frame's ``file_path`` ("" if none).
    """
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, RecursionError, ValueError) as exc:
        raise CameraFileError(f"{p}: not a JSON file ({type(exc).__name__})") from None
    return nerf_cameras(doc, p, width=width, height=height, near=near, far=far,
                        drop_distortion=drop_distortion)


def nerf_cameras(doc: Any, p: Path, *, width: int | None = None, height: int | None = None,
                 near: float | None = None, far: float | None = None,
                 drop_distortion: bool = False) -> tuple[list[Camera], list[str]]:
    """`read_nerf` of an already parsed document ``doc`` read from ``p``."""
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        raise CameraFileError(f"{p}: a transforms.json is an object with a \"frames\" list")
    near, far = _clip_range(near, far, f"{p} (NeRF transforms)")
    cameras: list[Camera] = []
    names: list[str] = []
    for i, frame in enumerate(doc["frames"]):
        where = f"{p}: frame {i}"
        if not isinstance(frame, dict):
            raise CameraFileError(f"{where}: expected an object, got {type(frame).__name__}")
        d = {**doc, **frame}

        def num(key: str, d: dict = d, where: str = where) -> float | None:
            return _nerf_number(d, key, where)

        w, h = _pixels(num("w"), "w", where), _pixels(num("h"), "h", where)
        for key, given, val in (("w", width, w), ("h", height, h)):
            if val is not None and given is not None and val != given:
                raise CameraFileError(f"{where}: {key!r} = {val:g} differs from the size "
                                      f"asked for ({width}x{height})")
        w_px = w if w is not None else width
        h_px = h if h is not None else height
        if w_px is None or h_px is None:
            raise CameraFileError(f"{where}: no image size ('w', 'h'): pass width= and "
                                  f"height= (CLI: --size)")
        fx, fy = num("fl_x"), num("fl_y")
        if fx is None:
            ax = num("camera_angle_x")
            if ax is None:
                raise CameraFileError(f"{where}: no focal length ('fl_x' or "
                                      f"'camera_angle_x')")
            if not 0.0 < ax < math.pi:
                raise CameraFileError(f"{where}: 'camera_angle_x' is in radians and must be "
                                      f"in (0, pi), got {ax:g}")
            fx = 0.5 * w_px / math.tan(0.5 * ax)
        if fy is None:
            ay = num("camera_angle_y")
            if ay is not None and not 0.0 < ay < math.pi:
                raise CameraFileError(f"{where}: 'camera_angle_y' is in radians and must be "
                                      f"in (0, pi), got {ay:g}")
            fy = fx if ay is None else 0.5 * h_px / math.tan(0.5 * ay)
        cx, cy = num("cx"), num("cy")
        cx = 0.5 * w_px if cx is None else cx
        cy = 0.5 * h_px if cy is None else cy
        model = str(d.get("camera_model", "OPENCV"))
        if d.get("is_fisheye") or model not in _NERF_PINHOLE_MODELS:
            # instant-ngp marks a fisheye lens with is_fisheye; nerfstudio names its models
            what = "a fisheye lens (is_fisheye)" if d.get("is_fisheye") else f"model {model!r}"
            raise CameraFileError(f"{where}: {what} is not a pinhole camera; clraster renders "
                                  f"pinhole cameras only (known: "
                                  f"{', '.join(_NERF_PINHOLE_MODELS)})")
        coeffs = {k: num(k) or 0.0 for k in _NERF_DISTORTION}
        _distortion(model, coeffs, drop_distortion, where)
        m = frame.get("transform_matrix")
        try:
            pose = np.asarray(m, dtype=np.float64)
        except (TypeError, ValueError):
            pose = np.zeros(0)
        if pose.shape == (3, 4):
            pose = np.vstack([pose, [0.0, 0.0, 0.0, 1.0]])
        if pose.shape != (4, 4):
            raise CameraFileError(f"{where}: 'transform_matrix' must be a 4x4 (or 3x4) "
                                  f"matrix of numbers")
        # nerfstudio / instant-ngp pixel centres at (i + 0.5, j + 0.5); OpenCV's K at (i, j)
        k = _intrinsics(fx, fy, cx - 0.5, cy - 0.5)
        cameras.append(_make(k, w_px, h_px, pose, "opengl", near, far, where))
        fp = frame.get("file_path", "")
        names.append(fp if isinstance(fp, str) else "")
    if not cameras:
        raise CameraFileError(f"{p}: no frames")
    return cameras, names


def _npz_array(z: Any, key: str, where: str) -> np.ndarray | None:
    if key not in z.files:
        return None
    try:
        a = z[key]
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        # an object array (needs pickle, refused), a corrupt member
        raise CameraFileError(f"{where}: array {key!r} cannot be read ({exc})") from None
    if a.dtype.kind not in "fiu" and key not in ("convention",):
        raise CameraFileError(f"{where}: array {key!r} must be numeric, got {a.dtype}")
    return a


def read_npz(path: str | os.PathLike, *, width: int | None = None, height: int | None = None,
             near: float | None = None, far: float | None = None) -> list[Camera]:
    """Cameras from a NumPy ``.npz``: ``K`` (3, 3) shared or (N, 3, 3) per view, OpenCV's
    pixel convention (as `Camera.from_intrinsics`); ``poses`` (N, 4, 4) camera → world;
    optional ``convention`` (a string: ``"opencv"`` default or ``"opengl"``), ``near``,
    ``far``, ``width``, ``height`` (scalars; the arguments win where both are given and
    agree, and a clash of sizes is an error)."""
    p = Path(path)
    try:
        z = np.load(p, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise CameraFileError(f"{p}: not a NumPy .npz file ({exc})") from None
    if not hasattr(z, "files"):
        raise CameraFileError(f"{p}: a .npy array, not an .npz with 'K' and 'poses'")
    with z:
        k = _npz_array(z, "K", str(p))
        poses = _npz_array(z, "poses", str(p))
        if k is None or poses is None:
            raise CameraFileError(f"{p}: needs arrays 'K' and 'poses' (has "
                                  f"{', '.join(z.files) or 'none'})")
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise CameraFileError(f"{p}: 'poses' must be (N, 4, 4), got {poses.shape}")
        n = poses.shape[0]
        if n == 0:
            raise CameraFileError(f"{p}: 'poses' holds no pose")
        if k.shape == (3, 3):
            k = np.broadcast_to(k, (n, 3, 3))
        if k.shape != (n, 3, 3):
            raise CameraFileError(f"{p}: 'K' must be (3, 3) or ({n}, 3, 3) for {n} poses, "
                                  f"got {k.shape}")
        conv = "opencv"
        if "convention" in z.files:
            conv = str(_npz_array(z, "convention", str(p)))
            if conv not in CONVENTIONS:
                raise CameraFileError(f"{p}: 'convention' must be one of {list(CONVENTIONS)}, "
                                      f"got {conv!r}")
        stored: dict[str, float] = {}
        for key in ("near", "far", "width", "height"):
            a = _npz_array(z, key, str(p))
            if a is not None:
                if a.size != 1:
                    raise CameraFileError(f"{p}: {key!r} must be a scalar, got shape {a.shape}")
                stored[key] = float(a.reshape(()))
    size = {}
    for key, given in (("width", width), ("height", height)):
        if key in stored:
            stored[key] = float(_pixels(stored[key], key, str(p)) or 0)
        if key in stored and given is not None and stored[key] != given:
            raise CameraFileError(f"{p}: {key} {stored[key]:g} differs from the size asked "
                                  f"for ({width}x{height})")
        val = given if given is not None else stored.get(key)
        if val is None:
            raise CameraFileError(f"{p}: no image size: store 'width' and 'height' in the "
                                  f"file or pass width= and height= (CLI: --size)")
        size[key] = int(val)
    near = near if near is not None else stored.get("near")
    far = far if far is not None else stored.get("far")
    near, far = _clip_range(near, far, f"{p} (an .npz without 'near'/'far')")
    return [_make(np.asarray(k[i], np.float64), size["width"], size["height"],
                  np.asarray(poses[i], np.float64), conv, near, far, f"{p}: view {i}")
            for i in range(n)]


def common_size(cameras: list[Any]) -> tuple[int, int] | None:
    """The one image size the size-bound cameras of a list share (`Camera.image_size`);
    None if none is bound to a size. Raises ValueError if they differ: a batch renders at
    one size."""
    sizes = {c.image_size for c in cameras
             if isinstance(c, Camera) and c.image_size is not None}
    if len(sizes) > 1:
        listed = ", ".join(f"{w}x{h}" for w, h in sorted(sizes))
        raise ValueError(f"the cameras are for images of different sizes ({listed}); a batch "
                         f"renders at one size: split the cameras by size")
    return sizes.pop() if sizes else None
