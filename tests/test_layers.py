"""The package's layers: every module imports only its own layer and those below it, no two
modules import each other (directly or around a loop), and the public modules' short names
(`clraster._aliases`) are the layered modules themselves."""

from __future__ import annotations

import ast
import importlib
import pickle
import subprocess
import sys
from pathlib import Path

import pytest

import clraster
from clraster import _aliases

PACKAGE = Path(clraster.__file__).resolve().parent

#: bottom up; a module may import its own layer and the layers before it
LAYERS = ("base", "world", "clip", "culling", "output", "pipeline", "scale", "viewer",
          "entrances")
#: modules outside the layer packages: the package face, the old names, the command lines
ENTRANCES = {"clraster", "clraster._aliases", "clraster.cli", "clraster.cmdline",
             "clraster.demo"}


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        if parts[1] == "bench":   # the benchmark harness sits above everything
            continue
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def _layer(module: str) -> int:
    parts = module.split(".")
    if module in ENTRANCES or len(parts) < 2:
        return LAYERS.index("entrances")
    return LAYERS.index(parts[1])


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The clraster modules ``name`` imports anywhere (top level, functions, TYPE_CHECKING)."""
    is_pkg = path.name == "__init__.py"
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[:len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            for alias in node.names:
                sub = f"{mod}.{alias.name}"
                found.add(sub if sub in modules else mod)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return {m for m in found if m in modules and m != name}


def test_every_import_goes_down_or_across():
    modules = _modules()
    up = []
    for name, path in modules.items():
        for dep in _imports(name, path, modules):
            if _layer(dep) > _layer(name):
                up.append(f"{name} ({LAYERS[_layer(name)]}) imports {dep} "
                          f"({LAYERS[_layer(dep)]})")
    assert not up, "\n".join(up)


def test_no_import_circles():
    modules = _modules()
    graph = {name: _imports(name, path, modules) for name, path in modules.items()}
    # a package's face imports its modules; they may import the face's siblings freely
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> None:
        state[n] = 1
        stack.append(n)
        for d in sorted(graph[n]):
            if state.get(d) == 1:
                loop = stack[stack.index(d):] + [d]
                pytest.fail("import circle: " + " -> ".join(loop))
            if d not in state:
                visit(d)
        stack.pop()
        state[n] = 2

    for n in sorted(graph):
        if n not in state:
            visit(n)


@pytest.mark.parametrize("old", sorted(_aliases.OLD_PATHS))
def test_old_module_paths_are_the_new_modules(old):
    new = _aliases.OLD_PATHS[old]
    module = importlib.import_module(old)
    assert module is importlib.import_module(new)
    assert module.__name__ == new and module.__spec__.name == new
    assert sys.modules[old] is module
    assert getattr(clraster, old.rpartition(".")[2]) is module


def test_old_paths_of_package_modules_and_from_imports():
    import clraster.reference.lines as old_lines
    from clraster.reference.lines import render_lines
    from clraster.scenes import plant
    from clraster.views import load_cameras

    import clraster.pipeline.reference.lines as new_lines
    from clraster.world.generators import building

    assert old_lines is new_lines and render_lines is new_lines.render_lines
    assert plant is building.plant
    assert load_cameras.__module__ == "clraster.world.views"
    assert importlib.import_module("clraster.scenes.building") is building


def test_objects_of_moved_modules_pickle_by_their_new_path():
    from clraster.views import ViewError

    err = ViewError(3, "near", "near must be > 0")
    blob = pickle.dumps(err)
    assert b"clraster.world.views" in blob
    back = pickle.loads(blob)
    assert (back.index, back.field, back.message) == (3, "near", "near must be > 0")
    assert pickle.loads(pickle.dumps(clraster.RasterConfig())) == clraster.RasterConfig()


def test_import_clraster_and_the_old_names_stay_off_opencl():
    code = ("import sys, clraster, clraster.views, clraster.shade, clraster.scenes; "
            "print('pyopencl' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120)
    assert out.stdout.strip() == "False"
