"""The module paths clraster had before its modules were grouped by layer: each old name
(``clraster.views``, ``clraster.renderer``, ...) is the new module itself, imported when
first asked for (``import clraster.views``, ``from clraster.views import load_cameras``,
``clraster.views``), so ``clraster.views is clraster.world.views``. A package's old name
covers its modules too (``clraster.reference.lines``). Objects defined in these modules
carry the new paths, so pickles (Dask) name the new modules."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
from types import ModuleType

#: old module → the module it became (packages: their modules follow by prefix)
OLD_PATHS = {
    "clraster.arraypool": "clraster.pipeline.arraypool",
    "clraster.atomic": "clraster.output.atomic",
    "clraster.batch": "clraster.scale.batch",
    "clraster.camera": "clraster.world.camera",
    "clraster.clip2d": "clraster.clip.clip2d",
    "clraster.composite": "clraster.scale.composite",
    "clraster.config": "clraster.base.config",
    "clraster.device": "clraster.pipeline.device",
    "clraster.distributed": "clraster.scale.distributed",
    "clraster.fates": "clraster.culling.fates",
    "clraster.frame": "clraster.output.frame",
    "clraster.inputs": "clraster.world.inputs",
    "clraster.lines": "clraster.pipeline.lines",
    "clraster.mesh": "clraster.world.mesh",
    "clraster.occlusion": "clraster.pipeline.occlusion",
    "clraster.outputs": "clraster.output.outputs",
    "clraster.precision": "clraster.world.precision",
    "clraster.reference": "clraster.pipeline.reference",
    "clraster.renderer": "clraster.pipeline.renderer",
    "clraster.scene": "clraster.world.scene",
    "clraster.scenes": "clraster.world.generators",
    "clraster.shade": "clraster.output.shade",
    "clraster.views": "clraster.world.views",
    "clraster.window": "clraster.clip.window",
}


def new_name(name: str) -> str | None:
    """The module an old ``name`` became (a package's module too), or None."""
    if name in OLD_PATHS:
        return OLD_PATHS[name]
    head, _, tail = name.rpartition(".")
    while head:
        if head in OLD_PATHS:
            return f"{OLD_PATHS[head]}.{name[len(head) + 1:]}"
        head, _, _ = head.rpartition(".")
    return None


class _Loader(importlib.abc.Loader):
    """Hands the import system the new module under the old name."""

    def __init__(self, new: str) -> None:
        self.new = new
        self.spec: importlib.machinery.ModuleSpec | None = None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        module = importlib.import_module(self.new)
        self.spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        # the import system set the old name's spec on the module: give it back its own
        module.__spec__ = self.spec


class AliasFinder(importlib.abc.MetaPathFinder):
    """Finds the old module paths (first on ``sys.meta_path``, so an old package's name
    never reaches the file finders, which would load its modules a second time)."""

    def find_spec(self, fullname: str, path: object = None, target: object = None
                  ) -> importlib.machinery.ModuleSpec | None:
        new = new_name(fullname)
        if new is None:
            return None
        return importlib.util.spec_from_loader(fullname, _Loader(new),
                                               is_package=fullname in _PACKAGES)


_PACKAGES = {"clraster.reference", "clraster.scenes"}


def install() -> None:
    """Put `AliasFinder` first on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, AliasFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, AliasFinder())
