"""Peer renderer for the benchmark harness: Mesa's llvmpipe (OpenGL on the CPU) via moderngl.

The same mesh or scene, camera matrix and image size as clraster, drawn through a conformant
OpenGL 4.5 with depth test LESS (clear 1.0), back-face culling (counter-clockwise front
faces) and no MSAA, into a headless EGL framebuffer; the depth buffer is read back and put in
clraster's conventions, so frames compare pixel for pixel:

* row 0 is the top row (glReadPixels returns the bottom row first: flipped here);
* window depth ``d = (z/w + 1) / 2`` in [0, 1] (default glDepthRange 0..1, clip control
  NEGATIVE_ONE_TO_ONE), 1.0 for background;
* clip = ``M @ [x, y, z, 1]`` with ``M = view_proj @ model`` formed per instance in float64
  on the host and rounded to float32 once, exactly as clraster does (drawlist.instance_matrices),
  then passed to GL column-major (numpy is row-major: the matrix is transposed on upload).

Depth attachment: ``GL_DEPTH_COMPONENT32F``. moderngl (5.8..5.13) only makes 24-bit depth
textures, so the texture it creates is re-specified as 32F through the GL entry points from
``eglGetProcAddress``; if that fails the 24-bit buffer is kept and `LlvmpipePeer.depth_format`
says so. A colour attachment (R32I) receives the triangle id ``face_base[instance] +
gl_PrimitiveID`` — roughly the per-fragment output work clraster does (it writes ids and
barycentrics); read it back with ``render(..., ids=True)``.

Geometry is uploaded once (`LlvmpipePeer.upload`): one vertex + index buffer per distinct
mesh, and one instanced draw per distinct mesh with a per-instance ``mat4`` attribute, so a
scene of thousands of instances (the procedural plant: 5,408 instances) is a few dozen draw
calls (43).

User clip planes (``render(..., clip_planes=...)``): up to 8 world-space planes (a, b, c, d)
keeping a·x + b·y + c·z + d >= 0, through ``gl_ClipDistance[i]`` with GL_CLIP_DISTANCE0 + i
enabled for the planes given. Each plane is taken to object space per instance on the host
(``plane @ model`` in float64, rounded to float32 once, like the matrices) and passed as a
per-instance attribute, so the distance is the plane's value at the object-space vertex and
GL's clipper interpolates it linearly in clip space, the semantics clraster follows. Frames
without planes use the plain shader (no clip distances written), unchanged.

Install: ``pip install 'clraster[peers]'`` (moderngl, glcontext) and, on Debian/Ubuntu,
``apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libgl1`` (GLVND's libEGL, Mesa's EGL
vendor, the gallium drivers with llvmpipe, and libGL, which glcontext's EGL backend loads).
Before the first context this module sets, unless already set, ``LIBGL_ALWAYS_SOFTWARE=1``
and ``GALLIUM_DRIVER=llvmpipe`` (Mesa then picks llvmpipe even where a GPU driver exists);
EGL devices 0..3 are tried and a non-llvmpipe renderer (e.g. a vendor GPU driver) is
refused, since the peer is meant to be the CPU OpenGL. ``LP_NUM_THREADS=n`` sets llvmpipe's
raster threads (default: the CPU count); it is recorded in every `PeerFrame`.

Load order: see `_load_opencl_first` (OpenCL ICDs are enumerated before Mesa is loaded).
Depth: clraster interpolates depth over vertices snapped to 1/256 pixel, llvmpipe over the
unsnapped float vertices, so depths differ by up to |grad d| / 512 per pixel (~1e-7 typical).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import re
import statistics
import time
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

__all__ = ["INSTALL_HINT", "LlvmpipePeer", "PeerFrame", "coverage_agreement", "probe"]

INSTALL_HINT = ("pip install 'clraster[peers]' (moderngl); Debian/Ubuntu: apt-get install "
                "libegl1 libegl-mesa0 libgl1-mesa-dri libgl1")

#: EGL devices tried, in order, for one whose renderer is llvmpipe.
_EGL_DEVICES = 4

_VERTEX_SHADER = """
#version 330
in vec3 in_pos;
in mat4 in_mvp;        // per instance: view_proj @ model, float32
in int in_base;        // per instance: face_base of the instance
flat out int v_base;
void main() {
    gl_Position = in_mvp * vec4(in_pos, 1.0);
    v_base = in_base;
}
"""

# The same shader, plus 8 user clip distances. The object-space planes of an instance are
# two mat4 attributes, one plane per column (a mat4 attribute takes 4 locations: 1 + 4 + 1 +
# 8 = 14 of the 16 GL 3.3 guarantees). All 8 distances are written; those of planes not
# given are zero and their GL_CLIP_DISTANCEi is disabled, so they are ignored.
_CLIP_VERTEX_SHADER = """
#version 330
in vec3 in_pos;
in mat4 in_mvp;        // per instance: view_proj @ model, float32
in int in_base;        // per instance: face_base of the instance
in mat4 in_planes_a;   // per instance: object-space planes 0..3, one per column
in mat4 in_planes_b;   // per instance: object-space planes 4..7
flat out int v_base;
out float gl_ClipDistance[8];
void main() {
    vec4 p = vec4(in_pos, 1.0);
    gl_Position = in_mvp * p;
    v_base = in_base;
    gl_ClipDistance[0] = dot(in_planes_a[0], p);
    gl_ClipDistance[1] = dot(in_planes_a[1], p);
    gl_ClipDistance[2] = dot(in_planes_a[2], p);
    gl_ClipDistance[3] = dot(in_planes_a[3], p);
    gl_ClipDistance[4] = dot(in_planes_b[0], p);
    gl_ClipDistance[5] = dot(in_planes_b[1], p);
    gl_ClipDistance[6] = dot(in_planes_b[2], p);
    gl_ClipDistance[7] = dot(in_planes_b[3], p);
}
"""

_FRAGMENT_SHADER = """
#version 330
flat in int v_base;
out int out_id;
void main() {
    out_id = v_base + gl_PrimitiveID;
}
"""

# GL enums for the depth32f re-specification
_GL_TEXTURE_2D = 0x0DE1
_GL_DEPTH_COMPONENT = 0x1902
_GL_DEPTH_COMPONENT32F = 0x8CAC
_GL_FLOAT = 0x1406
_GL_TEXTURE_INTERNAL_FORMAT = 0x1003
# GL_CLIP_DISTANCE0 + i enables user clip distance i (moderngl has no flag for it:
# Context.enable_direct / disable_direct take the raw enum)
_GL_CLIP_DISTANCE0 = 0x3000
#: gl_ClipDistance slots the clip shader writes (GL_MAX_CLIP_DISTANCES is at least 8)
_CLIP_PLANES_MAX = 8


def _lp_threads() -> int | None:
    v = os.environ.get("LP_NUM_THREADS")
    try:
        return int(v) if v is not None else None
    except ValueError:
        return None


def _describe(info: dict) -> str:
    """'llvmpipe (LLVM 15.0.6, 256 bits), Mesa 22.3.6, OpenGL 4.5 core' from ctx.info."""
    renderer = str(info.get("GL_RENDERER", "?"))
    version = str(info.get("GL_VERSION", ""))
    m = re.match(r"\s*(\d+\.\d+)", version)
    gl = m.group(1) if m else version
    mesa = re.search(r"Mesa\s+(\S+)", version)
    profile = " core" if "core" in version.lower() else ""
    parts = [renderer]
    if mesa:
        parts.append(f"Mesa {mesa.group(1)}")
    parts.append(f"OpenGL {gl}{profile}")
    return ", ".join(parts)


def _load_opencl_first() -> None:
    """Load the OpenCL ICDs (clGetPlatformIDs) before Mesa is loaded.

    Mesa dlopens its driver, linked to the shared libLLVM, with RTLD_GLOBAL. An OpenCL ICD
    with a statically linked LLVM (the pip PoCL's libpocl, Oclgrind's runtime) loaded after
    that registers its LLVM command-line options into the shared LLVM's registry and LLVM
    aborts the whole process ("Option '...' registered more than once!"). Loaded the other
    way round, both work. So: enumerate the OpenCL platforms first (cheap; nothing is built).
    """
    try:
        from ..pipeline.device import platforms
        platforms()   # PoCL's threads start here (clraster.device: pinned where safe)
    except Exception:  # noqa: BLE001 - no OpenCL is fine for the peer itself
        pass


def _create_context():
    """(context, description) of a headless EGL context on llvmpipe, or (None, reason)."""
    try:
        import moderngl
    except ImportError as exc:
        return None, f"moderngl is not installed ({exc}); install: {INSTALL_HINT}"
    _load_opencl_first()
    os.environ.setdefault("LIBGL_ALWAYS_SOFTWARE", "1")
    os.environ.setdefault("GALLIUM_DRIVER", "llvmpipe")
    reasons = []
    for dev in range(_EGL_DEVICES):
        kw: dict[str, Any] = {"device_index": dev} if dev else {}
        try:
            # (moderngl's stub types **settings as dicts, hence the ignore)
            ctx = moderngl.create_standalone_context(
                backend="egl", require=330, **kw)  # type: ignore[arg-type]
        except Exception as exc:  # noqa: BLE001 - glcontext raises plain Exception
            reasons.append(f"EGL device {dev}: {type(exc).__name__}: {exc}")
            if dev == 0:
                continue
            break
        desc = _describe(ctx.info)
        if "llvmpipe" in str(ctx.info.get("GL_RENDERER", "")).lower():
            return ctx, desc
        reasons.append(f"EGL device {dev}: renderer is {desc!r}, not Mesa's llvmpipe (the "
                       f"peer is meant to be the CPU OpenGL)")
        ctx.release()
    return None, ("no headless EGL context with Mesa llvmpipe: " + "; ".join(reasons)
                  + f". Install: {INSTALL_HINT}")


_PROBE: tuple[bool, str] | None = None


def probe() -> tuple[bool, str]:
    """(True, "llvmpipe (LLVM 15.0.6, 256 bits), Mesa 22.3.6, OpenGL 4.5 core") when a
    headless EGL context with Mesa's llvmpipe can be created, else (False, reason), the
    reason saying what failed and what to install. Never raises; the answer is cached for
    the process (a context is created and released once)."""
    global _PROBE
    if _PROBE is None:
        try:
            ctx, desc = _create_context()
            if ctx is None:
                _PROBE = (False, desc)
            else:
                ctx.release()
                _PROBE = (True, desc)
        except Exception as exc:  # noqa: BLE001 - never raises
            _PROBE = (False, f"{type(exc).__name__}: {exc}; install: {INSTALL_HINT}")
    return _PROBE


def _gl_function(name: str, *argtypes):
    """A GL entry point of the current context through eglGetProcAddress."""
    lib = ctypes.util.find_library("EGL") or "libEGL.so.1"
    egl = ctypes.CDLL(lib)
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    ptr = egl.eglGetProcAddress(name.encode())
    if not ptr:
        raise RuntimeError(f"eglGetProcAddress({name}) returned NULL")
    return ctypes.CFUNCTYPE(None, *argtypes)(ptr)


def _make_depth32f(tex, width: int, height: int) -> bool:
    """Re-specify moderngl's (24-bit) depth texture ``tex`` as GL_DEPTH_COMPONENT32F; True if
    the driver reports the new internal format. The context must be current."""
    u, i = ctypes.c_uint, ctypes.c_int
    try:
        bind = _gl_function("glBindTexture", u, u)
        image = _gl_function("glTexImage2D", u, i, i, i, i, i, u, u, ctypes.c_void_p)
        query = _gl_function("glGetTexLevelParameteriv", u, i, u, ctypes.POINTER(i))
        bind(_GL_TEXTURE_2D, tex.glo)
        image(_GL_TEXTURE_2D, 0, _GL_DEPTH_COMPONENT32F, width, height, 0,
              _GL_DEPTH_COMPONENT, _GL_FLOAT, None)
        fmt = i(0)
        query(_GL_TEXTURE_2D, 0, _GL_TEXTURE_INTERNAL_FORMAT, ctypes.byref(fmt))
        bind(_GL_TEXTURE_2D, 0)
        return fmt.value == _GL_DEPTH_COMPONENT32F
    except Exception:  # noqa: BLE001 - fall back to the 24-bit buffer
        return False


@dataclass
class PeerFrame:
    """One llvmpipe frame in clraster's conventions.

    Attributes:
        depth: (H, W) float32 window depth in [0, 1], 1.0 background, row 0 = top.
        times_ms: one per timed frame: clear + all draws + glFinish (no read-back).
        readback_ms: median time of reading the depth buffer back (glReadPixels + flip).
        renderer: the GL_RENDERER string.
        threads: LP_NUM_THREADS if set, else None (llvmpipe's default: the CPU count).
        depth_format: "depth32f" or "depth24" (the fallback if 32F could not be set up).
        triangle_id: (H, W) int32 ids (``face_base[instance] + face``, −1 background) when
            rendered with ``ids=True``, else None.
    """

    depth: np.ndarray
    times_ms: list[float]
    readback_ms: float
    renderer: str
    threads: int | None
    depth_format: str = "depth32f"
    triangle_id: np.ndarray | None = field(default=None, repr=False)

    @property
    def coverage(self) -> np.ndarray:
        """(H, W) bool: pixels drawn (depth < 1)."""
        return self.depth < 1.0

    @property
    def median_ms(self) -> float:
        return statistics.median(self.times_ms)


class _Group:
    """The GL objects of one distinct mesh and the scene instances that draw it, all
    mirroring (negative determinant: drawn with glFrontFace(GL_CW)) or none."""

    __slots__ = ("instances", "vbo", "ibo", "mvp", "base", "vao", "n_faces", "mirrored",
                 "planes", "clip_vao")

    def __init__(self, mirrored: bool = False) -> None:
        self.instances: list[int] = []
        self.mirrored = mirrored
        # moderngl objects (Buffer, VertexArray), made by upload
        self.vbo: Any = None
        self.ibo: Any = None
        self.mvp: Any = None
        self.base: Any = None
        self.vao: Any = None
        # made by the first render with clip planes: per-instance object-space planes
        # (8 × vec4 float32) and the vertex array of the clip program
        self.planes: Any = None
        self.clip_vao: Any = None
        self.n_faces = 0

    def release(self) -> None:
        for name in ("vao", "clip_vao", "vbo", "ibo", "mvp", "base", "planes"):
            obj = getattr(self, name)
            if obj is not None:
                obj.release()
                setattr(self, name, None)


class LlvmpipePeer:
    """A headless llvmpipe context and framebuffer of ``width × height`` pixels.

    Raises:
        RuntimeError: no llvmpipe EGL context can be created (the message is probe()'s
            reason, with what to install).
    """

    def __init__(self, width: int, height: int) -> None:
        w, h = int(width), int(height)
        if w <= 0 or h <= 0:
            raise ValueError(f"width and height must be positive, got {width}x{height}")
        ctx, desc = _create_context()
        if ctx is None:
            raise RuntimeError(desc)
        self.width, self.height = w, h
        self.ctx = ctx
        self.description = desc
        self.renderer = str(ctx.info["GL_RENDERER"])
        self._groups: list[_Group] = []
        self._transforms: np.ndarray | None = None
        self._clip_prog: Any = None   # the clip-distance program, made on first use
        self.n_faces = 0
        with ctx:
            self._depth = ctx.depth_texture((w, h))
            self.depth_format = "depth32f" if _make_depth32f(self._depth, w, h) else "depth24"
            self._ids = ctx.renderbuffer((w, h), 1, dtype="i4")
            self.fbo = ctx.framebuffer(color_attachments=[self._ids],
                                       depth_attachment=self._depth)
            self.prog = ctx.program(vertex_shader=_VERTEX_SHADER,
                                    fragment_shader=_FRAGMENT_SHADER)

    # -- geometry ---------------------------------------------------------------------------
    def upload(self, target) -> None:
        """Upload a `clraster.Mesh` or `clraster.Scene` (replacing what was uploaded).

        Each distinct mesh's vertices (float32) and faces (uint32) are uploaded once (twice
        when it has both mirroring and ordinary instances); the scene's instances are grouped
        by mesh and by whether their transform mirrors, each group drawn with one instanced
        call. Mirroring groups are drawn with the front face clockwise, so their faces keep
        their outward side, the Scene rule clraster follows (glTF 2.0). Meshes without
        faces are skipped.
        """
        from clraster.world.mesh import Mesh
        from clraster.world.scene import Scene
        if isinstance(target, Mesh):
            meshes, transforms, bases = [target], np.eye(4)[None], np.zeros(1, np.int64)
        elif isinstance(target, Scene):
            meshes = [inst.mesh for inst in target.instances]
            transforms = np.asarray(target.transforms(), np.float64).reshape(-1, 4, 4)
            bases = np.asarray(target.face_base, np.int64)
        else:
            raise TypeError(f"target must be a clraster.Mesh or Scene, got "
                            f"{type(target).__name__}")
        if int(target.n_faces) >= 2**31:
            raise ValueError("triangle ids are int32: at most 2**31 - 1 faces")
        self._free_geometry()
        by_mesh: dict[tuple[int, bool], _Group] = {}
        order: list[tuple[_Group, Mesh]] = []
        mirrored = np.linalg.det(transforms[:, :3, :3]) < 0.0
        for k, mesh in enumerate(meshes):
            key = (id(mesh), bool(mirrored[k]))
            g = by_mesh.get(key)
            if g is None:
                g = by_mesh[key] = _Group(key[1])
                order.append((g, mesh))
            g.instances.append(k)
        ctx = self.ctx
        with ctx:
            for g, mesh in order:
                faces = np.asarray(mesh.faces)
                if faces.shape[0] == 0:
                    continue
                g.n_faces = int(faces.shape[0])
                idx = np.asarray(g.instances)
                g.vbo = ctx.buffer(np.ascontiguousarray(mesh.vertices, np.float32))
                g.ibo = ctx.buffer(np.ascontiguousarray(faces, np.int32).view(np.uint32))
                g.mvp = ctx.buffer(reserve=64 * idx.size, dynamic=True)
                g.base = ctx.buffer(bases[idx].astype(np.int32))
                g.vao = ctx.vertex_array(
                    self.prog,
                    [(g.vbo, "3f", "in_pos"), (g.mvp, "16f/i", "in_mvp"),
                     (g.base, "i/i", "in_base")],
                    index_buffer=g.ibo, index_element_size=4)
                self._groups.append(g)
        self._transforms = transforms
        self.n_faces = int(target.n_faces)

    @property
    def n_draws(self) -> int:
        """Draw calls per frame (one instanced draw per distinct non-empty mesh, and per
        mirroring or not)."""
        return len(self._groups)

    # -- frames -----------------------------------------------------------------------------
    def render(self, view_proj, *, cull: str = "back", repeat: int = 5, warmup: int = 1,
               ids: bool = False, clip_planes=None) -> PeerFrame:
        """Draw what was uploaded, ``warmup`` untimed frames then ``repeat`` timed ones.

        Args:
            view_proj: (4, 4) world → clip matrix for column vectors (float64 is fine), or a
                camera with ``view_projection(width, height)``.
            cull: "back", "front" or "none"; counter-clockwise is front (glFrontFace CCW).
            repeat: timed frames (>= 1); each is clear + all draws + glFinish.
            warmup: untimed frames first (the first frame includes llvmpipe's shader JIT).
            ids: also read back the triangle ids (untimed).
            clip_planes: None, or (K, 4) world-space planes (a, b, c, d), 0 <= K <= 8,
                keeping the points with a·x + b·y + c·z + d >= 0 (gl_ClipDistance; checked
                by `clraster.base.checks.check_clip_planes`, as clraster's render does).

        The per-instance matrices (``view_proj @ model`` in float64, rounded to float32) and
        object-space planes (``plane @ model``, likewise) are written once per call, before
        the frames, outside the timing.
        """
        if self._transforms is None:
            raise RuntimeError("upload() a mesh or scene first")
        if cull not in ("back", "front", "none"):
            raise ValueError(f"cull must be 'back', 'front' or 'none', got {cull!r}")
        if repeat < 1 or warmup < 0:
            raise ValueError(f"repeat must be >= 1 and warmup >= 0, got {repeat}, {warmup}")
        import moderngl
        if hasattr(view_proj, "view_projection"):
            view_proj = view_proj.view_projection(self.width, self.height)
        vp = np.asarray(view_proj, np.float64)
        if vp.shape != (4, 4):
            raise ValueError(f"view_proj must be (4, 4), got {vp.shape}")
        planes = None
        if clip_planes is not None:
            from clraster.base.checks import check_clip_planes
            planes = check_clip_planes(clip_planes)
        ctx, fbo = self.ctx, self.fbo
        with ctx:
            for g in self._groups:
                mvp = np.matmul(vp, self._transforms[g.instances]).astype(np.float32)
                # column-major for GL: the transpose of each row-major matrix, flattened
                g.mvp.write(np.ascontiguousarray(mvp.transpose(0, 2, 1)))
            if planes is not None:
                self._write_planes(planes)
            fbo.use()
            ctx.depth_func = "<"
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.front_face = "ccw"
            if cull == "none":
                ctx.disable(moderngl.CULL_FACE)
            else:
                ctx.enable(moderngl.CULL_FACE)
                ctx.cull_face = cull
            if planes is None:
                draws = [(g.vao, len(g.instances), "cw" if g.mirrored else "ccw")
                         for g in self._groups]
            else:
                draws = [(g.clip_vao, len(g.instances), "cw" if g.mirrored else "ccw")
                         for g in self._groups]
                for i in range(_CLIP_PLANES_MAX):
                    if i < planes.shape[0]:
                        ctx.enable_direct(_GL_CLIP_DISTANCE0 + i)
                    else:
                        ctx.disable_direct(_GL_CLIP_DISTANCE0 + i)

            def frame() -> None:
                fbo.clear(depth=1.0)
                for vao, n, front in draws:
                    ctx.front_face = front
                    vao.render(moderngl.TRIANGLES, instances=n)
                ctx.finish()

            for _ in range(warmup):
                frame()
            times, reads = [], []
            depth: np.ndarray | None = None
            for _ in range(repeat):
                t0 = time.perf_counter()
                frame()
                times.append((time.perf_counter() - t0) * 1e3)
                t0 = time.perf_counter()
                depth = self._read_depth()
                reads.append((time.perf_counter() - t0) * 1e3)
            depth = cast(np.ndarray, depth)   # repeat >= 1: read at least once
            tri = None
            if ids:
                raw = fbo.read(components=1, attachment=0, dtype="i4")
                tri = np.frombuffer(raw, np.int32).reshape(self.height, self.width)[::-1]
                tri = np.where(depth < 1.0, tri, -1).astype(np.int32)
            if planes is not None:
                # leave them off: the plain program writes no clip distances
                for i in range(_CLIP_PLANES_MAX):
                    ctx.disable_direct(_GL_CLIP_DISTANCE0 + i)
            err = ctx.error
        if err != "GL_NO_ERROR":
            raise RuntimeError(f"OpenGL error after rendering: {err}")
        return PeerFrame(depth=depth, times_ms=times, readback_ms=statistics.median(reads),
                         renderer=self.renderer, threads=_lp_threads(),
                         depth_format=self.depth_format, triangle_id=tri)

    def _write_planes(self, planes: np.ndarray) -> None:
        """Write each group's per-instance object-space planes (``plane @ model`` in float64,
        rounded to float32; zero rows for the unused slots) for (K, 4) float64 world
        ``planes``, making the clip program and vertex arrays on first use. The context
        must be current."""
        ctx = self.ctx
        if self._clip_prog is None:
            self._clip_prog = ctx.program(vertex_shader=_CLIP_VERTEX_SHADER,
                                          fragment_shader=_FRAGMENT_SHADER)
        assert self._transforms is not None
        k = planes.shape[0]
        for g in self._groups:
            n = len(g.instances)
            obj = np.zeros((n, _CLIP_PLANES_MAX, 4), np.float64)
            # a world point x is kept iff plane · (model @ x_obj) >= 0, i.e. (plane @ model)
            # · x_obj >= 0: the object-space plane is the row vector plane @ model
            obj[:, :k] = np.matmul(planes[None], self._transforms[g.instances])
            if g.clip_vao is None:
                g.planes = ctx.buffer(reserve=4 * _CLIP_PLANES_MAX * 4 * n, dynamic=True)
                g.clip_vao = ctx.vertex_array(
                    self._clip_prog,
                    [(g.vbo, "3f", "in_pos"), (g.mvp, "16f/i", "in_mvp"),
                     (g.base, "i/i", "in_base"),
                     (g.planes, "16f 16f/i", "in_planes_a", "in_planes_b")],
                    index_buffer=g.ibo, index_element_size=4)
            # a mat4 attribute's column i is the i-th vec4 in memory: plane i per column
            g.planes.write(np.ascontiguousarray(obj.astype(np.float32)))

    def _read_depth(self) -> np.ndarray:
        raw = self.fbo.read(components=1, attachment=-1, dtype="f4")
        d = np.frombuffer(raw, np.float32).reshape(self.height, self.width)
        return np.ascontiguousarray(d[::-1])   # GL row 0 is the bottom row

    # -- clean-up ---------------------------------------------------------------------------
    def _free_geometry(self) -> None:
        for g in self._groups:
            g.release()
        self._groups = []

    def release(self) -> None:
        """Free every GL object and the context (idempotent)."""
        ctx = getattr(self, "ctx", None)
        if ctx is None:
            return
        with ctx:
            self._free_geometry()
            for obj in (self.fbo, self._ids, self._depth, self.prog, self._clip_prog):
                if obj is not None:
                    obj.release()
            self._clip_prog = None
        ctx.release()
        self.ctx = None

    def __enter__(self) -> LlvmpipePeer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def coverage_agreement(clraster_depth, peer_depth) -> dict:
    """Compare two depth images (or objects with a ``.depth``) of the same size.

    A pixel is covered iff its depth < 1 (NaN counts as background). Returns a dict:
    ``pixels``; ``agree`` (fraction of pixels whose coverage agrees: both drawn or both
    background) and ``agree_pixels``; ``both``, ``clraster_only``, ``peer_only`` (pixel
    counts); and over the pixels both cover, ``depth_diff_median``, ``depth_diff_p99`` and
    ``depth_diff_max`` of |depth difference| (None if no pixel is covered by both).
    """
    a = np.asarray(getattr(clraster_depth, "depth", clraster_depth), np.float64)
    b = np.asarray(getattr(peer_depth, "depth", peer_depth), np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"depth images must be 2-D and the same shape, got {a.shape} and "
                         f"{b.shape}")
    ca, cb = a < 1.0, b < 1.0
    n = int(a.size)
    both = ca & cb
    agree = int(np.count_nonzero(ca == cb))
    out = {
        "pixels": n,
        "agree": agree / n if n else 1.0,
        "agree_pixels": agree,
        "both": int(np.count_nonzero(both)),
        "clraster_only": int(np.count_nonzero(ca & ~cb)),
        "peer_only": int(np.count_nonzero(cb & ~ca)),
        "depth_diff_median": None, "depth_diff_p99": None, "depth_diff_max": None,
    }
    if out["both"]:
        d = np.abs(a[both] - b[both])
        out["depth_diff_median"] = float(np.median(d))
        out["depth_diff_p99"] = float(np.percentile(d, 99))
        out["depth_diff_max"] = float(d.max())
    return out
