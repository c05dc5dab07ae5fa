"""One writer per output folder: an exclusive ``fcntl.flock`` on ``FOLDER/.lock`` held for the whole run.

Every command that writes an output folder (``train``, ``train --seeds``, ``evaluate``, ``render``, ``sweep``) holds
:func:`output_lock` on it from before its first write to after its last. A second writer is refused at once with one
line naming the folder and the holder's pid. The kernel releases a ``flock`` when its holder exits, however it exits
(``kill -9`` included), so the lock of a dead process never blocks; the lock file itself is removed when the holder
ends normally. Taking the lock also removes the temporary files that an interrupted atomic write
(:mod:`sb3_latentswarm.utils.atomic`) left in the folder and its subfolders: nobody else can be writing them while the
lock is held (a subfolder with a lock file of its own is another run's folder, and is left alone).

``flock`` holds between processes of one machine, and on NFS v4 between machines. Within one process the lock is
re-entrant: a run that evaluates into its own folder does not refuse itself.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path

from sb3_latentswarm.utils.atomic import remove_stale_temporaries

__all__ = ["LOCK_NAME", "OutputInUseError", "output_lock"]

LOCK_NAME = ".lock"
"""The lock file of an output folder."""

_HELD: dict[Path, int] = {}  # folders this process holds, with their depth of nesting


class OutputInUseError(ValueError):
    """Another process is writing the output folder (it holds its lock)."""


def _holder(handle: int) -> str:
    with contextlib.suppress(OSError):
        text = os.pread(handle, 200, 0).decode("utf-8", "replace").strip()
        if text:
            return text.splitlines()[0]
    return "another process"


def _acquire(path: Path, folder: Path) -> int:
    """Open and lock ``path``; retry when a holder that was ending removed the file between our open and our lock."""
    for _ in range(100):
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise OutputInUseError(
                f"{folder} is in use by another run ({holder}); wait for it to end, or choose another --output"
            ) from None
        except OSError:
            os.close(fd)
            raise
        try:
            same = os.stat(path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)  # the file we locked was removed by a holder that just ended: lock the new one
    raise OutputInUseError(f"{folder}: could not take its lock {path} (it keeps changing)")


@contextlib.contextmanager
def output_lock(folder: str | os.PathLike[str]) -> Iterator[Path]:
    """Hold the output folder ``folder`` (created if missing, with its missing parents, and those removed again if
    still empty at the end) for this process; yield it.

    :raises OutputInUseError: (a ``ValueError``) when another process holds it, naming the folder and the holder
        (pid, host, start time)
    :raises ValueError: when ``folder`` exists and is not a folder
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"output folder {folder} is an existing file, not a folder")
    created = [path for path in (folder, *folder.parents) if not path.exists()]  # the folder and new parents, deepest first
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"output folder {folder} is not writable: {error.strerror or error}") from None
    key = folder.resolve()
    if key in _HELD:
        _HELD[key] += 1
        try:
            yield folder
        finally:
            _HELD[key] -= 1
        return
    path = folder / LOCK_NAME
    try:
        fd = _acquire(path, folder)
    except OSError as error:  # a read-only folder, a lock file that is a symlink
        raise ValueError(f"output folder {folder} is not writable (its lock {path}: {error.strerror or error})") from None
    _HELD[key] = 1
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()} since {time.strftime('%Y-%m-%d %H:%M:%S')}\n".encode(), 0)
        remove_stale_temporaries(folder, skip_marker=LOCK_NAME)
        yield folder
    finally:
        del _HELD[key]
        with contextlib.suppress(OSError):
            path.unlink()  # still holding the lock: a process that opened the old file retries on the new one
        os.close(fd)  # releases the lock
        for path in created:  # a run refused before writing anything leaves no empty folder (nor parent) behind
            try:
                path.rmdir()
            except OSError:  # not empty: it holds results, or another run's folder
                break
