"""Write a file whole or not at all: a temporary file beside it, then a rename over it.

`write_atomic` is what every file writer of clraster uses (`clraster.outputs.write_output`,
`clraster.batch.render_views`' view files and records). The temporary file lives in the
destination's folder (a rename is atomic only within one file system) under the name::

    .{final name}.{host}-{pid}-{thread}.tmp

``host`` is 6 hex digits of a hash of the machine's name, ``pid`` the writing process and
``thread`` its native thread id, so two writers never share a temporary, and a temporary
left behind by a process that died (SIGKILL, power loss: nothing ran to delete it) can be
told from one a live writer owns (`stale_temporary`). The temporary name never exceeds the
file system's longest name (``NAME_MAX``, `os.pathconf`): when the final name is too long for
the suffix, its start is kept and the rest replaced by ``~`` and 8 hex digits of a hash of the
whole name, so a final name as long as the file system allows can be written, and an error
about the temporary never replaces the one the user should see.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

__all__ = ["name_max", "pid_alive", "stale_temporary", "temporary_name", "write_atomic"]

#: the longest file name assumed where the file system does not say (POSIX's NAME_MAX on
#: Linux, macOS and Windows' NTFS alike)
DEFAULT_NAME_MAX = 255

#: the temporary names `temporary_name` makes (group "final": the final name, shortened
#: with ``~hash`` when it had to be)
TEMPORARY_RE = re.compile(r"^\.(?P<final>.+)\.(?P<host>[0-9a-f]{6})-(?P<pid>\d+)-(?P<tid>\d+)"
                          r"\.tmp$", re.DOTALL)


def _host_tag() -> str:
    return hashlib.blake2b(socket.gethostname().encode("utf-8", "surrogateescape"),
                           digest_size=3).hexdigest()


_HOST = _host_tag()


def name_max(folder: str | os.PathLike) -> int:
    """The longest file name (in bytes) ``folder``'s file system takes: ``NAME_MAX`` from
    `os.pathconf`, or `DEFAULT_NAME_MAX` where it cannot say (Windows, a missing folder)."""
    try:
        n = os.pathconf(folder, "PC_NAME_MAX")
    except (AttributeError, OSError, ValueError):
        return DEFAULT_NAME_MAX
    return n if isinstance(n, int) and n > 0 else DEFAULT_NAME_MAX


def _cut(text: str, nbytes: int) -> str:
    """The longest start of ``text`` whose file-system encoding fits ``nbytes`` (whole
    characters only)."""
    out, used = [], 0
    for ch in text:
        n = len(os.fsencode(ch))
        if used + n > nbytes:
            break
        out.append(ch)
        used += n
    return "".join(out)


def temporary_name(final: str, limit: int = DEFAULT_NAME_MAX) -> str:
    """The temporary name (module docstring) this thread writes ``final`` under, at most
    ``limit`` bytes long."""
    tail = f".{_HOST}-{os.getpid()}-{threading.get_native_id()}.tmp"
    name = f".{final}{tail}"
    if len(os.fsencode(name)) <= limit:
        return name
    # keep the start (a person finding it sees whose it is) and tell names that share their
    # start apart by a hash of the whole final name
    mark = "~" + hashlib.blake2b(os.fsencode(final), digest_size=4).hexdigest()
    room = limit - len(os.fsencode(f".{mark}{tail}"))
    return f".{_cut(final, max(0, room))}{mark}{tail}"


def write_atomic(path: str | os.PathLike, write: Callable[[BinaryIO], object] | bytes
                 ) -> None:
    """Write ``path`` whole or not at all: ``write(file object)`` (or the bytes ``write``)
    into a temporary file in ``path``'s folder (`temporary_name`), then `os.replace` it onto
    ``path`` (atomic on POSIX and Windows within one folder). On any error the temporary
    is deleted and ``path`` is as it was. The file gets the umask's permissions, as a file
    written in place would.

    Raises:
        OSError: ENAMETOOLONG naming ``path`` when its name is longer than its file system
            allows (before anything is written); any error of the write or the rename.
    """
    p = Path(path)
    folder = p.parent
    limit = name_max(folder if str(folder) else ".")
    if len(os.fsencode(p.name)) > limit:
        raise OSError(errno.ENAMETOOLONG,
                      f"file name is {len(os.fsencode(p.name))} bytes long; this file system "
                      f"allows at most {limit}: choose a shorter name", str(p))
    tmp = p.with_name(temporary_name(p.name, limit))
    fd = _create_new(tmp)
    try:
        with os.fdopen(fd, "wb") as fh:
            if isinstance(write, (bytes, bytearray, memoryview)):
                fh.write(write)
            else:
                write(fh)
            # on disk before it takes the final name: after a power loss the final name holds
            # the old file or the whole new one, never an empty or partial one
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, p)
    except BaseException:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise


def _create_new(tmp: Path) -> int:
    """A new file at ``tmp`` for writing, never through a link and never someone else's.

    The temporary name is predictable, so in a folder others can write to, a link planted
    at it would redirect the write (and then be renamed onto the output). O_EXCL|O_NOFOLLOW
    refuse to open anything that exists; what exists at the name (a leftover of a process
    whose id was reused, or a planted link) is removed, never followed, and the creation
    tried once more — where it cannot be removed (another user's file in a sticky folder)
    the error says so."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) \
        | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    try:
        return os.open(tmp, flags, 0o666)
    except FileExistsError:
        tmp.unlink()        # a link is removed, not its target
        return os.open(tmp, flags, 0o666)


def stale_temporary(name: str, *, any_writer: bool = False) -> str | None:
    """The final name (start) of ``name`` if it is a temporary of `write_atomic` whose writer
    is gone — a process of this machine that no longer runs, or with ``any_writer`` (when
    the caller knows no writer of that folder is left) any writer — else None.

    A process id can be reused: a temporary whose id now belongs to another process is kept
    (wrongly, but safely), never one of a live writer deleted."""
    m = TEMPORARY_RE.match(name)
    if m is None:
        return None
    if not any_writer and (m["host"] != _HOST or pid_alive(int(m["pid"]))):
        return None
    return m["final"]


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this machine (True where it cannot tell)."""
    if pid <= 0 or os.name == "nt":   # Windows' os.kill would terminate the process
        return True
    try:
        os.kill(pid, 0)   # signal 0: only the existence and permission checks
    except ProcessLookupError:
        return False
    except (PermissionError, OSError, OverflowError):
        return True   # someone else's process (or no way to ask): leave its files alone
    return True
