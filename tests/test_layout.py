"""Python and OpenCL C agree on every shared constant and record layout.

clraster/layout.py is the one source of the constants and records the host shares with the
kernels; `clraster.layout.c_header` generates their C text into kernels/common.h. Here:

* A probe kernel (kernels/layout.cl), built through `clraster.device.program` like every
  stage, writes what the compiler sees — the value of each generated ``#define`` (float ones
  as their bits), sizeof / offsetof / field sizes of each generated struct, and the values of
  common.h's derived macros — and the test compares them with the Python constants and the
  NumPy dtypes' itemsize and field offsets.
* The comparison can fail: the same probe built from a source with one define and one field
  type changed by hand reports exactly those differences.
* No kernel file keeps a hand-written copy (``#define`` of a generated name, a struct of a
  generated record), and the Python modules that used to keep copies now hold the very
  objects from clraster.layout.
"""

from __future__ import annotations

import re

import numpy as np
import pyopencl as cl
import pytest

from clraster.base import layout
from clraster.base.config import RasterConfig
from clraster.pipeline.device import default_context, kernel_dir, kernel_source, program


def probe_entries(cfg: RasterConfig) -> list[tuple[str, str, int]]:
    """(label, C integer expression, expected value) for everything the probe checks; the
    expected values come from the Python objects, not from the generated C text."""
    out = []
    for _, names in layout.C_DEFINES:
        for name in names:
            v = getattr(layout, name)
            if isinstance(v, np.float32):
                out.append((name, f"(long)as_uint({name})", int(v.view(np.uint32))))
            else:
                out.append((name, f"(long)({name})", int(v)))
    # common.h's derived macros
    out += [("SUB_ONE", "(long)(SUB_ONE)", layout.SUBPIXEL_ONE),
            ("SUB_HALF", "(long)(SUB_HALF)", layout.SUBPIXEL_ONE // 2),
            ("TILE_SIZE", "(long)(TILE_SIZE)", cfg.tile_size)]
    for cname, var in layout.C_RECORDS.items():
        dt = getattr(layout, var)
        out.append((f"sizeof({cname})", f"(long)sizeof({cname})", dt.itemsize))
        for field in dt.names:
            fdt, offset = dt.fields[field][:2]
            out.append((f"offsetof({cname}, {field})",
                        f"(long)__builtin_offsetof({cname},{field})", offset))
            out.append((f"sizeof({cname}.{field})", f"(long)sizeof((({cname}*)0)->{field})",
                        fdt.itemsize))
    for _, expr, _ in out:
        assert " " not in expr   # build options are split at spaces
    return out


def run_probe(prg: cl.Program, ctx: cl.Context, n: int) -> np.ndarray:
    queue = cl.CommandQueue(ctx)
    out = np.full(n, -1, np.int64)
    buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    cl.Kernel(prg, "layout_probe")(queue, (1,), (1,), buf)
    cl.enqueue_copy(queue, out, buf, is_blocking=True)
    return out


def mismatches(entries, got: np.ndarray) -> list[str]:
    return [f"{label}: OpenCL C {int(g)}, Python {want}"
            for (label, _, want), g in zip(entries, got, strict=True) if int(g) != want]


def probe_options(cfg: RasterConfig, entries) -> tuple[str, ...]:
    return (*cfg.build_options(), "-DLAYOUT_PROBE=" + ",".join(e for _, e, _ in entries))


@pytest.mark.parametrize("tile_log2", [3, 6])
def test_compiler_sees_the_python_layout(tile_log2):
    ctx = default_context()
    cfg = RasterConfig(tile_log2=tile_log2)
    entries = probe_entries(cfg)
    prg = program(ctx, "layout", probe_options(cfg, entries))
    bad = mismatches(entries, run_probe(prg, ctx, len(entries)))
    assert not bad, "Python and OpenCL C disagree:\n" + "\n".join(bad)


def test_probe_detects_a_disagreement():
    """The same probe over a source with a define and a field type edited by hand fails on
    exactly those (so the test above is able to fail)."""
    ctx = default_context()
    cfg = RasterConfig()
    entries = probe_entries(cfg)
    src = kernel_source("layout")
    bad_src = src.replace("#define OC_INVALID 1024\n", "#define OC_INVALID 1025\n")
    bad_src = bad_src.replace("    int id;\n    int flags;\n", "    long id;\n    int flags;\n")
    assert bad_src.count("OC_INVALID 1025") == 1 and "long id;" in bad_src
    prg = cl.Program(ctx, bad_src).build(options=list(probe_options(cfg, entries)))
    bad = {m.split(":")[0] for m in mismatches(entries, run_probe(prg, ctx, len(entries)))}
    # long id (still at 32, already 8-aligned) moves the fields after it by 4 and rounds
    # Piece up to 104 bytes
    after = ("flags", "z0", "dzdx", "dzdy", "l1", "l1x", "l1y", "l2", "l2x", "l2y", "r1", "r2",
             "zlo", "cover", "pad")
    assert bad == {"OC_INVALID", "sizeof(Piece)", "sizeof(Piece.id)",
                   *(f"offsetof(Piece, {f})" for f in after)}


def test_kernels_keep_no_hand_copies():
    names = {n for _, group in layout.C_DEFINES for n in group}
    kdir = kernel_dir()
    files = sorted(kdir.glob("*.cl")) + [kdir / "common.h"]
    assert len(files) > 2
    for path in files:
        text = path.read_text()
        copies = set(re.findall(r"^\s*#\s*define\s+(\w+)", text, re.M)) & names
        assert not copies, f"{path.name} defines {sorted(copies)} by hand; clraster/layout.py " \
                           f"generates them"
        structs = set(re.findall(r"\}\s*(\w+)\s*;", text)) & set(layout.C_RECORDS)
        assert not structs, f"{path.name} declares {sorted(structs)} by hand"
    common = (kdir / "common.h").read_text()
    assert len(layout.LAYOUT_INCLUDE.findall(common)) == 1
    # every stage gets the generated text, once
    for path in kdir.glob("*.cl"):
        assert kernel_source(path.stem).count(layout.c_header().rstrip("\n")) == 1, path.name


def test_python_modules_use_the_layout_objects():
    from clraster.base import config
    from clraster.pipeline import occlusion
    from clraster.pipeline import segments as lines
    from clraster.pipeline.reference import lines as ref_lines
    from clraster.pipeline.reference import pyramid as ref_pyramid
    from clraster.pipeline.reference import query as ref_query
    from clraster.pipeline.reference import setup as ref_setup
    from clraster.pipeline.stages import lines as st_lines
    from clraster.pipeline.stages import pyramid as st_pyramid

    # the layout objects have one home: config (the tunables) does not hand them on
    for name in ("PIECE_DTYPE", "DRAW_DTYPE", "WINVERT_DTYPE", "WINXY_DTYPE", "CULL_MODES",
                 "STATUS_NAMES"):
        assert not hasattr(config, name), name
    for _, group in layout.C_DEFINES:
        for name in group:
            if hasattr(config, name):
                assert getattr(config, name) == getattr(layout, name), name
    assert ref_lines.LINE_DTYPE is layout.LINE_DTYPE and st_lines.LINE_DTYPE is layout.LINE_DTYPE
    for name in ("LS_ACCEPTED", "LS_CLIPPED", "LS_INVALID", "LS_REJECTED", "LS_CLIPPED_AWAY",
                 "LS_ACCEPTED_DEGENERATE", "LS_CLIPPED_DEGENERATE"):
        assert getattr(lines, name) == getattr(layout, name)
    for name in ("HIZ_EPS", "HIZ_DEPTH_SLACK", "HIZ_PIXEL_SLACK"):
        assert getattr(ref_pyramid, name) is getattr(layout, name)
    assert st_pyramid.PYR_LOG2 == layout.PYR_LOG2
    assert ref_query.BOX_TRIS == layout.BOX_TRIS
    assert ref_setup.POLY_MAX == layout.POLY_MAX
    assert [int(o) for o in occlusion.Occlusion] == [
        layout.OCC_VISIBLE, layout.OCC_OCCLUDED, layout.OCC_VIEW_CULLED]


@pytest.mark.parametrize("dtype", [
    np.dtype([("a", np.int8), ("b", np.int32)]),                       # b off its alignment
    np.dtype({"names": ["a"], "formats": [np.int32], "itemsize": 8}),  # trailing padding
    np.dtype({"names": ["a", "b"], "formats": [np.int32, np.int32], "offsets": [0, 8],
              "itemsize": 12}),                                         # a gap
    np.dtype([("a", np.int32, (2, 2))]),                                # 2-d field
    np.dtype([("a", np.float16)]),                                      # no C type here
])
def test_generator_refuses_layouts_c_would_not_reproduce(dtype):
    with pytest.raises(ValueError):
        layout.c_struct("Bad", dtype)
