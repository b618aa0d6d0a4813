"""Atomic file and directory writes: a crash never leaves a partial file under its final name, and
what is written is readable as any new file would be (0644 and 0755 with umask 022; temporary files
are created 0600 and opened up on success)."""

from __future__ import annotations

import contextlib
import glob
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from stratamap.core.errors import ConfigError


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _open_up(path: Path, directory: bool) -> None:
    """Give a finished temporary file or folder the mode an ordinary new one would have."""
    os.chmod(path, (0o777 if directory else 0o666) & ~_umask())


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is renamed onto ``path``.

    Use it for writers that want a file name (trimesh, PIL, numpy)::

        with atomic_path(out / "mesh.stl") as tmp:
            mesh.export(tmp, file_type="stl")
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        _open_up(tmp, directory=False)
        os.replace(tmp, final)
        _fsync_dir(final.parent)
    finally:
        tmp.unlink(missing_ok=True)


def write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    return write_bytes(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike[str], obj: Any, indent: int | None = 2) -> Path:
    return write_text(path, json.dumps(obj, indent=indent, sort_keys=False, default=_json_default) + "\n")


def _json_default(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def check_output_folder(path: str | os.PathLike[str], ours: Callable[[Path], bool], what: str) -> Path:
    """``path`` (absolute) if a command may write ``what`` there: it is new, an empty folder, or a
    folder ``ours`` recognises as an earlier output of the same command. A command never replaces
    files it did not write: anything else is a ConfigError naming the folder."""
    final = Path(path).expanduser().absolute()
    if final.exists() and not final.is_dir():
        raise ConfigError([("", f"{final} is a file, not a folder: choose a folder for the {what}")])
    if final.is_dir() and any(final.iterdir()) and not ours(final):
        raise ConfigError(
            [("", f"{final} holds files that are not a {what}: choose a new or empty folder (nothing was written)")]
        )
    return final


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield an empty staging directory; on success it replaces ``path`` as a whole.

    The old directory (if any) is moved aside first and removed only after the new one is in
    place, so at every instant ``path`` is either the complete old or the complete new content.
    An existing empty directory (the working directory, say) is kept and filled instead.
    """
    final = Path(path).expanduser().absolute()
    if final.exists() and not final.is_dir():
        raise ConfigError([("", f"{final} is a file, not a folder: nothing was written")])
    created = [d for d in (final.parent, *final.parent.parents) if not d.exists()]
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        _remove_stale_staging(final)
        staging = Path(tempfile.mkdtemp(prefix=f".{final.name}.{os.getpid()}.", suffix=".staging", dir=final.parent))
    except OSError as exc:
        _remove_empty(created)
        raise ConfigError([("", f"cannot write {final}: {exc.strerror or exc}")]) from None
    done = False
    try:
        yield staging
        _fsync_dir(staging)
        _open_up(staging, directory=True)
        if final.is_dir() and not any(final.iterdir()):
            for entry in staging.iterdir():
                os.replace(entry, final / entry.name)
            _fsync_dir(final)
            done = True
            return
        backup = None
        if final.exists():
            backup = final.with_name(f".{final.name}.{os.getpid()}.old")
            if backup.exists():
                shutil.rmtree(backup)
            os.replace(final, backup)
        os.replace(staging, final)
        _fsync_dir(final.parent)
        done = True
        if backup is not None:
            shutil.rmtree(backup, ignore_errors=True)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
        if not done:  # a failed write leaves no folder behind that was not there before
            _remove_empty(created)


def _remove_stale_staging(final: Path) -> None:
    """Staging folders of ``final`` left by writers that were killed (their process is gone)."""
    for staging in final.parent.glob(f".{glob.escape(final.name)}.*.staging"):
        pid = staging.name[len(final.name) + 2 :].split(".", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)) and staging.is_dir():
            shutil.rmtree(staging, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_empty(folders: list[Path]) -> None:
    """Remove these folders, innermost first, where they are still empty."""
    for folder in sorted(folders, key=lambda d: len(d.parts), reverse=True):
        with contextlib.suppress(OSError):
            folder.rmdir()
