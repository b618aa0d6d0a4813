"""Where stratamap's own files are: the checkout that holds ``configs/`` next to ``core/``; and
scratch folders that go when the process ends."""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

_SCRATCH: list[Path] = []


def repo_root() -> Path:
    """The checkout that holds configs/ (the CLI also works from an installed wheel with explicit paths)."""
    return Path(__file__).resolve().parent.parent


def scratch_dir(prefix: str) -> Path:
    """A new empty folder under the system's temporary folder, removed with what it holds when the
    process exits: the conformance kit's export folders and the sources' example recordings, which
    must outlive the call that made them (a cached stage's parameters name them) but not the run.
    Each `make test` used to leave some 40 of them behind, about 1 GB over a few dozen runs."""
    if not _SCRATCH:
        atexit.register(_remove_scratch)
    path = Path(tempfile.mkdtemp(prefix=prefix))
    _SCRATCH.append(path)
    return path


def _remove_scratch() -> None:
    while _SCRATCH:
        shutil.rmtree(_SCRATCH.pop(), ignore_errors=True)
