"""Atomic file and directory writes: a crash never leaves a partial file under its final name, and
what is written is readable as any new file would be (0644 and 0755 with umask 022; temporary files
are created 0600 and opened up on success)."""

from __future__ import annotations

import contextlib
import glob
import json
import os
import shutil
import signal
import tempfile
import threading
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


def output_target(path: str | os.PathLike[str]) -> Path:
    """The folder an output named ``path`` is written to (absolute): where ``path`` is a symbolic
    link, the folder it points to, so that the link stays and its target gets the new output."""
    final = Path(path).expanduser().absolute()
    if final.is_symlink():
        return Path(os.path.realpath(final))
    return final


def check_writable(final: Path) -> None:
    """A ConfigError now, before any work, when ``final`` (an output folder, absolute) could not be
    put in place at the end: the folder or the nearest existing folder above it is read-only or
    immutable."""
    if final.exists() and not os.access(final, os.W_OK | os.X_OK):
        raise ConfigError([("", f"cannot write {final}: the folder is read-only or immutable (nothing was written)")])
    parent = next((d for d in final.parents if d.exists()), None)
    if parent is not None and not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigError([("", f"cannot write {final}: {parent} is read-only or immutable (nothing was written)")])


def check_output_folder(path: str | os.PathLike[str], ours: Callable[[Path], bool], what: str) -> Path:
    """``path`` (absolute; a symbolic link's target) if a command may write ``what`` there: it is
    new, an empty folder, or a folder ``ours`` recognises as an earlier output of the same command,
    and it and its parent are writable. A command never replaces files it did not write: anything
    else is a ConfigError naming the folder."""
    final = output_target(path)
    if final.exists() and not final.is_dir():
        raise ConfigError([("", f"{final} is a file, not a folder: choose a folder for the {what}")])
    if final.is_dir() and any(final.iterdir()) and not ours(final):
        raise ConfigError(
            [("", f"{final} holds files that are not a {what}: choose a new or empty folder (nothing was written)")]
        )
    check_writable(final)
    return final


class _InterruptGuard:
    """SIGINT while an output folder is written: recorded, and raised as KeyboardInterrupt as usual
    except while the folder is being put in place (then only recorded). The record is what makes a
    Ctrl-C final: library code that swallows the KeyboardInterrupt (a bare ``except``, a finalizer
    it lands in) cannot make the run carry on to replace the previous output."""

    def __init__(self) -> None:
        self.count = 0
        self.deferred = False
        self.previous: Any = None

    def __call__(self, signum: int, frame: Any) -> None:
        self.count += 1
        if not self.deferred:
            raise KeyboardInterrupt

    def check(self) -> None:
        if self.count:
            raise KeyboardInterrupt


#: The guards of the output folders being written now (innermost last).
_ACTIVE: list[_InterruptGuard] = []


def raise_if_interrupted() -> None:
    """KeyboardInterrupt if a Ctrl-C came while an output folder is being written, even one that
    was swallowed: long jobs call it between steps, so that they stop then and not only at the end."""
    for guard in _ACTIVE:
        guard.check()


@contextlib.contextmanager
def _guarded() -> Iterator[_InterruptGuard]:
    guard = _InterruptGuard()
    # Handlers can be set from the main thread only; elsewhere (a worker thread) the guard just
    # never fires, and SIGINT reaches the main thread as it would have. Only Python's own handler is
    # replaced: an ignored SIGINT (a background job) or an application's handler stays as it is.
    installed = (
        threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    )
    if installed:
        guard.previous = signal.signal(signal.SIGINT, guard)
    _ACTIVE.append(guard)
    try:
        yield guard
    finally:
        _ACTIVE.remove(guard)
        if installed:
            signal.signal(signal.SIGINT, guard.previous)


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield an empty staging directory; on success it replaces ``path`` as a whole.

    The old directory (if any) is moved aside first and removed only after the new one is in
    place, so at every instant ``path`` is either the complete old or the complete new content.
    An existing empty directory (the working directory, say) is kept and filled instead. A symbolic
    link is written through: its target gets the new content. A Ctrl-C at any point before the
    swap, even one that the block's code swallowed, leaves the old content as it was and raises
    KeyboardInterrupt; one during the swap is honoured once it is done, by putting the old content back.
    """
    final = output_target(path)
    if final.exists() and not final.is_dir():
        raise ConfigError([("", f"{final} is a file, not a folder: nothing was written")])
    check_writable(final)
    created = [d for d in (final.parent, *final.parent.parents) if not d.exists()]
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        _remove_stale_staging(final)
        staging = Path(tempfile.mkdtemp(prefix=f".{final.name}.{os.getpid()}.", suffix=".staging", dir=final.parent))
    except OSError as exc:
        _remove_empty(created)
        raise ConfigError([("", f"cannot write {final}: {exc.strerror or exc}")]) from None
    done = False
    with _guarded() as guard:
        try:
            yield staging
            guard.check()
            _fsync_dir(staging)
            _open_up(staging, directory=True)
            guard.deferred = True
            guard.check()
            try:
                undo = _swap_in(staging, final)
            except OSError as exc:
                reason = exc.strerror or exc
                raise ConfigError([("", f"cannot write {final}: {reason} (nothing was replaced)")]) from None
            if guard.count:  # Ctrl-C during the swap: the old content goes back
                undo()
                raise KeyboardInterrupt
            done = True
            # From here the new content is in place for good: a Ctrl-C while the old one is removed
            # comes too late to undo it, and the command ends as it would have.
            undo.discard()
        finally:
            guard.deferred = True  # the cleanup below runs to its end; the interrupt is already on its way
            if staging.exists():
                shutil.rmtree(staging, ignore_errors=True)
            if not done:  # a failed write leaves no folder behind that was not there before
                _remove_empty(created)


class _Undo:
    """How to put the old content of an output folder back after :func:`_swap_in`, or forget it."""

    def __init__(self, staging: Path, final: Path, backup: Path | None, moved: list[str] | None):
        self.staging, self.final, self.backup, self.moved = staging, final, backup, moved

    def __call__(self) -> None:
        if self.moved is not None:  # an empty folder was filled: empty it again
            self.staging.mkdir(exist_ok=True)
            for name in self.moved:
                os.replace(self.final / name, self.staging / name)
            return
        os.replace(self.final, self.staging)
        if self.backup is not None:
            os.replace(self.backup, self.final)
        _fsync_dir(self.final.parent)

    def discard(self) -> None:
        if self.backup is not None:
            shutil.rmtree(self.backup, ignore_errors=True)


def _swap_in(staging: Path, final: Path) -> _Undo:
    """Put ``staging`` in place of ``final``; what it returns undoes that (until discarded)."""
    if final.is_dir() and not any(final.iterdir()):
        moved = []
        for entry in staging.iterdir():
            os.replace(entry, final / entry.name)
            moved.append(entry.name)
        _fsync_dir(final)
        return _Undo(staging, final, None, moved)
    backup = None
    if final.exists():
        backup = final.with_name(f".{final.name}.{os.getpid()}.old")
        if backup.exists():
            shutil.rmtree(backup)
        os.replace(final, backup)
    try:
        os.replace(staging, final)
    except OSError:
        if backup is not None:
            os.replace(backup, final)
        raise
    _fsync_dir(final.parent)
    return _Undo(staging, final, backup, None)


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
