"""What the command lines share (``clraster render``, ``clraster demo``): their output paths
checked before any work (`check_output_file`, `check_output_folder`), and their errors turned
into one line on stderr and an exit code (`run_guarded`; the codes are `clraster.cli`'s)."""

from __future__ import annotations

import errno
import os
import stat
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from .output.atomic import name_max
from .pipeline.device import ForkedProcessError, NoDeviceError, device_busy

__all__ = ["check_output_file", "check_output_folder", "run_guarded"]


def _kind(path: Path, option: str, shown: Path) -> str | None:
    """What `path` is, following links: "folder", "file" (anything else), or None where
    nothing is or can be (a missing name, a file used as a folder, a name too long for the
    file system). Any other error (a folder that cannot be searched, a link loop) is a
    ValueError naming `option` and the path the user gave (`shown`)."""
    try:
        st = path.stat()
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            return None   # cannot exist; the caller says which name is too long
        raise ValueError(f"{option} {str(shown)!r} cannot be used: {exc.strerror or exc} "
                         f"({str(path)!r})") from None
    return "folder" if stat.S_ISDIR(st.st_mode) else "file"


def _check_names(names: Sequence[str], folder: Path, option: str, shown: Path) -> None:
    """Refuse a name in `names` (to be made in `folder`, or below it) longer than the file
    system allows (``NAME_MAX`` bytes, `clraster.atomic.name_max`): the write would fail
    only after the render."""
    limit = name_max(folder)
    for name in names:
        size = len(os.fsencode(name))
        if size > limit:
            raise ValueError(f"{option} {str(shown)!r}: the name {_clip(name)!r} is {size} "
                             f"bytes, longer than the {limit} bytes a name may have on that "
                             f"file system; give a shorter name")


def _clip(name: str, keep: int = 40) -> str:
    return name if len(name) <= keep else f"{name[:keep // 2]}...{name[-keep // 2:]}"


def check_output_file(path: Path, option: str, suffixes: tuple[str, ...] | None = None) -> None:
    """Refuse an output path before rendering (not after): a folder, a missing or
    read-only folder, a read-only file, a name longer than the file system allows (bytes,
    ``PC_NAME_MAX``), no or the wrong suffix (without ``suffixes``: one imageio does not
    know as an image format). A link is checked where it points: the file is written
    there (`clraster.cli`'s all-or-none writes)."""
    target = Path(os.path.realpath(path))
    folder = target.parent
    shown_folder = folder if os.path.islink(path) else path.parent
    kind = _kind(folder, option, path)
    if kind is None:
        _check_names(folder.parts[1:], Path(folder.anchor or "."), option, path)
        raise ValueError(f"{option} {str(path)!r}: folder {str(shown_folder)!r} does not "
                         f"exist")
    if kind != "folder":
        raise ValueError(f"{option} {str(path)!r}: {str(shown_folder)!r} is a file, not a "
                         f"folder")
    _check_names([target.name], folder, option, path)
    if _kind(target, option, path) == "folder":
        raise ValueError(f"{option} {str(path)!r} is a folder; give a file name")
    if not os.access(folder, os.W_OK | os.X_OK) or (
            target.exists() and not os.access(target, os.W_OK)):
        raise ValueError(f"{option} {str(path)!r} cannot be written (permission denied)")
    suffix = path.suffix.lower()
    if suffixes is None:
        if not suffix:
            raise ValueError(f"{option} {str(path)!r} has no file extension; give one that "
                             f"names the image format, e.g. .png")
        from imageio.config import known_extensions

        if suffix not in known_extensions:
            raise ValueError(f"{option} {str(path)!r}: {suffix} is not an image format "
                             f"imageio knows; use e.g. .png, .jpg or .tif")
    elif suffixes and suffix not in suffixes:   # (): the caller checks the suffix
        raise ValueError(f"{option} {str(path)!r} must end in {' or '.join(suffixes)} "
                         f"(it is written as a NumPy array file)")


def check_output_folder(path: Path, option: str, *, parents: bool = False) -> None:
    """Refuse, before any work, a folder for output files that cannot be used: an existing
    file, a missing parent folder (with `parents`, missing folders are made: the nearest
    existing one must be a folder), a name longer than the file system allows, no
    permission to write in it (or to make it). (``clraster render --views``, ``clraster
    demo``.)"""
    folder = Path(os.path.realpath(path))
    kind = _kind(folder, option, path)
    if kind == "folder":
        if not os.access(folder, os.W_OK | os.X_OK):
            raise ValueError(f"{option} {str(path)!r}: cannot write in that folder "
                             f"(permission denied)")
        return
    if kind is not None:
        raise ValueError(f"{option} {str(path)!r} is a file; give a folder")
    missing = [folder.name]   # the folders to make, outermost last
    parent = folder.parent
    while (kind := _kind(parent, option, path)) is None and parent != parent.parent:
        if not parents:
            break
        missing.append(parent.name)
        parent = parent.parent
    if kind is None:
        _check_names(parent.parts[1:], Path(parent.anchor or "."), option, path)
        raise ValueError(f"{option} {str(path)!r}: folder {str(parent)!r} does not exist")
    if kind != "folder":
        raise ValueError(f"{option} {str(path)!r}: {str(parent)!r} is a file, not a folder")
    _check_names(missing[::-1], parent, option, path)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {str(path)!r}: cannot make the folder in {str(parent)!r} "
                         f"(permission denied)")


def run_guarded(prog: str, command: Callable[[], int]) -> int:
    """Run a command's body; the errors a user can cause or fix become one line on stderr
    and an exit code (see the module docstring), never a traceback."""
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
