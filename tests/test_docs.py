"""The documentation names what exists: docs/ARCHITECTURE.md (the map of the code) names
every kernel file and package folder, only paths and modules that exist, each stage's three
mirrors and the layers in tests/test_layers.py's order; the other docs' module names and
paths resolve too (old module paths through `clraster._aliases`)."""

from __future__ import annotations

import importlib
import importlib.util
import re
from pathlib import Path
from types import ModuleType

import pytest

import clraster
from clraster import _aliases

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = Path(clraster.__file__).resolve().parent
ARCH = ROOT / "docs" / "ARCHITECTURE.md"
OTHER_DOCS = ("README.md", "docs/DEVELOPING.md", "docs/OTHER_TOOLS.md", "docs/DISTRIBUTED.md")
KERNELS = ROOT / "kernels"
#: kernels/ files that are no pipeline stage (the C/Python layout probe of tests/test_layout.py)
NOT_STAGES = {"layout"}

#: dotted names under clraster (modules, and objects in them)
_MODULE = re.compile(r"(?<![\w./-])clraster(?:\.[A-Za-z_]\w*)+")
#: repository paths: a top-level folder, then a path
_PATH = re.compile(r"(?<![\w./-])(?:clraster|kernels|tests|bench|docs|scripts)/[\w./*-]*")
_CODE_SPAN = re.compile(r"`([^`\n]+)`")
#: relative Markdown links to files of the repository
_LINK = re.compile(r"\]\((?!https?:|#|mailto:)([^)\s#]+)(?:#[^)]*)?\)")


def _text(doc: str | Path) -> str:
    return (ROOT / doc).read_text(encoding="utf-8")


def resolve(name: str) -> object:
    """The module or object ``name`` (``clraster.a.b.C.attr``) names: the longest prefix that
    imports as a module, then attributes. AttributeError/ModuleNotFoundError otherwise."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj: object = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError as exc:
            if not (exc.name or "").startswith("clraster"):
                raise   # a missing dependency, not a missing clraster module
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(name)


def _module_of(name: str) -> str:
    """The module part of a resolvable dotted ``name``."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        if isinstance(resolve(".".join(parts[:i])), ModuleType):
            return ".".join(parts[:i])
    return parts[0]


def _paths(text: str) -> set[str]:
    """Repository paths inside code spans, without glob patterns."""
    found = set()
    for span in _CODE_SPAN.findall(text):
        for p in _PATH.findall(span):
            p = p.rstrip(".")
            if "*" not in p:
                found.add(p)
    return found


def _missing_paths(doc: str | Path) -> list[str]:
    text = _text(doc)
    base = (ROOT / doc).parent
    bad = [p for p in sorted(_paths(text)) if not (ROOT / p).exists()]
    bad += [f"link {ln}" for ln in sorted(set(_LINK.findall(text)))
            if not (base / ln).exists()]
    return bad


def _unresolved(doc: str | Path) -> list[str]:
    bad = []
    for name in sorted(set(_MODULE.findall(_text(doc)))):
        try:
            resolve(name)
        except (AttributeError, ModuleNotFoundError) as exc:
            bad.append(f"{name}: {exc}")
    return bad


def _section(text: str, heading: str) -> str:
    start = text.index(heading)
    end = text.find("\n## ", start + len(heading))
    return text[start:end if end >= 0 else len(text)]


def _stages() -> list[str]:
    return sorted(p.stem for p in KERNELS.glob("*.cl") if p.stem not in NOT_STAGES)


def _packages() -> list[str]:
    return sorted(str(p.parent.relative_to(ROOT)) + "/" for p in PACKAGE.rglob("__init__.py")
                  if "__pycache__" not in p.parts)


# ---- docs/ARCHITECTURE.md ----------------------------------------------------------------

def test_architecture_paths_exist():
    assert not _missing_paths(ARCH), _missing_paths(ARCH)


def test_architecture_modules_resolve_by_their_new_homes():
    assert not _unresolved(ARCH), _unresolved(ARCH)
    old = [n for n in sorted(set(_MODULE.findall(_text(ARCH))))
           if _aliases.new_name(_module_of(n)) is not None]
    assert not old, f"name the layered modules, not their old paths: {old}"


def test_architecture_file_names_are_full_paths():
    # a bare `chain.py` could be anywhere: the map names files from the repository root,
    # except in the layer table, whose rows name files inside their row's folder
    text = _text(ARCH)
    table = _section(text, "## Layers")
    bare = []
    for span in _CODE_SPAN.findall(text.replace(table, "")):
        if span.startswith("#"):   # C text (`#include "layout.h"`)
            continue
        bare += [t for t in re.findall(r"[\w./-]+\.(?:py|cl|h)\b", span)
                 if not (ROOT / t).exists()]
    for row in table.splitlines():
        cells = row.split("|")
        folder = re.findall(r"`([\w/]+/)`", cells[2]) if len(cells) > 4 else []
        for span in _CODE_SPAN.findall(cells[3]) if folder else ():
            bare += [f"{folder[0]}{t}" for t in re.findall(r"[\w./-]+\.py\b", span)
                     if not (ROOT / folder[0] / t).exists()]
    assert not bare, bare


def test_architecture_names_every_kernel_file():
    text = _text(ARCH)
    missing = [f"kernels/{p.name}" for p in sorted(KERNELS.iterdir())
               if p.suffix in (".cl", ".h") and f"`kernels/{p.name}`" not in text]
    assert not missing, missing


@pytest.mark.parametrize("stage", _stages())
def test_every_stage_has_its_three_mirrors(stage):
    mirrors = (f"kernels/{stage}.cl", f"clraster/pipeline/stages/{stage}.py",
               f"clraster/pipeline/reference/{stage}.py")
    assert all((ROOT / m).is_file() for m in mirrors), mirrors
    row = [ln for ln in _section(_text(ARCH), "## Stages").splitlines()
           if f"`kernels/{stage}.cl`" in ln]
    assert row and all(f"`{m}`" in row[0] for m in mirrors), \
        f"docs/ARCHITECTURE.md's stage table needs a row naming {mirrors}"


def test_every_package_folder_is_in_the_layer_table():
    table = _section(_text(ARCH), "## Layers")
    missing = [p for p in _packages() if f"`{p}`" not in table]
    assert not missing, missing


def test_layer_table_follows_the_checked_layers():
    spec = importlib.util.spec_from_file_location("_test_layers", ROOT / "tests" /
                                                  "test_layers.py")
    assert spec and spec.loader
    layers_mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(layers_mod)
    rows = [row.split("|")[1].strip() for row in _section(_text(ARCH), "## Layers").splitlines()
            if row.startswith("| ") and row.split("|")[1].strip()]
    named = [r for r in rows if r in layers_mod.LAYERS]
    assert named == list(layers_mod.LAYERS), (named, layers_mod.LAYERS)


def test_architecture_code_names_occur_in_the_code():
    # `FrameParams.make`, `stream_draws`, `VERTEX_LANES`: each part is a word of the source
    words: set[str] = set()
    for path in [*PACKAGE.rglob("*.py"), *KERNELS.iterdir()]:
        words.update(re.findall(r"\w+", path.read_text(encoding="utf-8")))
    ident = re.compile(r"[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*")
    unknown = []
    for span in set(_CODE_SPAN.findall(_text(ARCH))):
        span = span.removesuffix("()")
        if not ident.fullmatch(span) or span.startswith("clraster.") \
                or re.search(r"\.(?:py|cl|h|md)$", span):
            continue
        unknown += [f"{span} ({part})" for part in span.split(".") if part not in words]
    assert not unknown, sorted(unknown)


# ---- the other docs ----------------------------------------------------------------------

@pytest.mark.parametrize("doc", OTHER_DOCS)
def test_doc_module_names_resolve(doc):
    assert not _unresolved(doc), _unresolved(doc)


@pytest.mark.parametrize("doc", OTHER_DOCS)
def test_doc_paths_exist(doc):
    assert not _missing_paths(doc), _missing_paths(doc)


def test_architecture_tunables_are_where_it_says():
    # every RasterConfig field is named, and every constant named is in config or layout
    import dataclasses

    from clraster.base import config, layout

    text = _section(_text(ARCH), "## Shared definitions")
    bullet = text[text.index("- **Tunables**"):]
    bullet = bullet[:bullet.find("\n- ")]
    spans = set(_CODE_SPAN.findall(bullet))
    fields = {f.name for f in dataclasses.fields(config.RasterConfig)}
    assert fields <= spans, f"RasterConfig fields the map does not name: {fields - spans}"
    lower = {s for s in spans if re.fullmatch(r"[a-z_][a-z0-9_]*", s)}
    assert lower <= fields, f"not RasterConfig fields: {lower - fields}"
    upper = {s for s in spans if re.fullmatch(r"[A-Z][A-Z0-9_]+", s)}
    missing = {s for s in upper if not hasattr(config, s) and not hasattr(layout, s)}
    assert not missing, f"neither in clraster.base.config nor in layout: {missing}"
