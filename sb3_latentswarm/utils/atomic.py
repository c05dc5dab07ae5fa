"""Atomic result files: write a temporary file in the target's folder, then ``os.replace`` it into place.

A failure while writing (a full disk, a size limit, a Ctrl-C) leaves the earlier file untouched and no partial file
under the final name. Every result this package writes (models, checkpoints, tables, JSON records, plots) goes
through :func:`atomic_path`.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = [
    "atomic_path", "check_real_path", "json_values", "probe_writable", "read_json", "remove_stale_temporaries", "write_bytes",
    "write_json", "write_text",
]

#: The names :func:`atomic_path` and :func:`probe_writable` give their temporary files (``tempfile.mkstemp``'s 8 random
#: characters between a fixed prefix and suffix).
_TEMPORARY = re.compile(r"^\.(?:.+\.[a-z0-9_]{8}\.tmp(?:\.[A-Za-z0-9]{1,16})?|write-probe\.[a-z0-9_]{8})$")


def _file_mode(final: Path) -> int:
    """The permission bits for a result file at ``final``: those of the file it replaces, else ``0o666 & ~umask``."""
    try:
        return final.stat().st_mode & 0o777
    except OSError:
        umask = os.umask(0o022)  # reading the umask means setting it; put it back at once
        os.umask(umask)
        return 0o666 & ~umask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is moved onto ``path`` with ``os.replace``.

    The temporary name keeps ``path``'s suffix (libraries that pick a format from the suffix still work). The file
    gets the permissions a plain ``open(path, "w")`` would give (``0o666`` less the process umask), or those of the
    file it replaces, not ``mkstemp``'s owner-only ``0o600``. On any exception the temporary file is removed and
    ``path`` is left as it was.
    """
    final = Path(path)
    if not final.parent.is_dir():  # (mkstemp would name its temporary file, not the path asked for)
        raise FileNotFoundError(f"cannot write {os.fspath(path)!r}: the folder {os.fspath(final.parent)!r} does not exist")
    fd, tmp_name = tempfile.mkstemp(prefix=f".{final.stem}.", suffix=f".tmp{final.suffix}", dir=final.parent)
    try:
        os.fchmod(fd, _file_mode(final))
    finally:
        os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        with open(tmp, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    write_bytes(path, text.encode("utf-8"))


def json_values(obj: Any) -> Any:
    """``obj`` as it reads back from JSON (tuples as lists; what JSON cannot hold, such as a schedule, as its
    ``repr``): to compare settings in memory with settings read from a file."""
    return json.loads(json.dumps(obj, default=repr))


def write_json(path: str | os.PathLike[str], obj: Any) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically."""
    write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def probe_writable(folder: str | os.PathLike[str], room_bytes: int = 0) -> None:
    """Raise ``ValueError`` unless ``folder`` (created if missing) accepts a file of ``room_bytes`` bytes.

    Called before training or evaluation starts, so an unwritable or full output folder fails in the first second,
    not after hours of work.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"output folder {folder} is an existing file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-probe.", dir=folder)
        try:
            with os.fdopen(fd, "wb") as handle:
                if room_bytes > 0:
                    handle.write(b"\0" * room_bytes)
                    handle.flush()
                    os.fsync(handle.fileno())
        finally:
            os.unlink(probe)
    except OSError as error:
        raise ValueError(
            f"output folder {folder} is not writable or has no room for {room_bytes} bytes: {error.strerror or error}"
        ) from None


def remove_stale_temporaries(folder: str | os.PathLike[str], depth: int = 3, skip_marker: str | None = None) -> list[Path]:
    """Remove the temporary files that interrupted atomic writes left in ``folder`` and its subfolders (``depth``
    levels, symlinks not followed); return them.

    Call it only while holding the folder's lock (:func:`sb3_latentswarm.utils.locks.output_lock` does), so that no
    write in progress loses its file.

    :param skip_marker: a subfolder holding a file of this name (another run's lock) is left alone, with all below it:
        it is another output folder, cleaned when its own lock is taken
    """
    removed: list[Path] = []
    level = [Path(folder)]
    for _ in range(depth + 1):
        below = []
        for current in level:
            try:
                entries = list(os.scandir(current))
            except OSError:
                continue
            for entry in entries:
                if entry.is_dir(follow_symlinks=False):
                    if skip_marker is None or not os.path.lexists(os.path.join(entry.path, skip_marker)):
                        below.append(Path(entry.path))
                elif entry.is_file(follow_symlinks=False) and _TEMPORARY.match(entry.name):
                    with contextlib.suppress(OSError):
                        os.unlink(entry.path)
                        removed.append(Path(entry.path))
        level = below
    return removed


def read_json(path: str | os.PathLike[str]) -> Any:
    """The JSON in ``path``; a damaged file is a ``ValueError`` naming it (the parser's own message names no file).

    :raises ValueError: for a file that is not UTF-8 JSON, or holds an integer too long to convert
    """
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as error:
        raise ValueError(f"{path} is damaged: it is not valid JSON ({error})") from None


def check_real_path(path: str | os.PathLike[str], root: str | os.PathLike[str], what: str) -> None:
    """Refuse ``path`` when it, or a folder between ``root`` and it, is a symlink, or when it lies outside ``root``:
    a result folder's files must be its own (a link could make one run continue or report another's files).

    :param what: what ``path`` is, for the message (``"trial folder"``, ``"model file"``)
    :raises ValueError: naming the path and what it points to
    """
    path, root = Path(path), Path(root)
    current = path
    while True:
        if current.is_symlink():
            raise ValueError(
                f"{current} is a symlink (to {os.readlink(current)}); a {what} must be a real "
                f"{'file' if current == path and not path.is_dir() else 'folder'} inside {root}: copy it there or move it out"
            )
        if current == root or current.parent == current:
            break
        current = current.parent
    if not path.resolve().is_relative_to(root.resolve()):
        raise ValueError(f"{path} lies outside {root}; a {what} must be inside it")
