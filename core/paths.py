"""Where stratamap's own files are: the checkout that holds ``configs/`` next to ``core/``."""

from __future__ import annotations

from pathlib import Path


def repo_root() -> Path:
    """The checkout that holds configs/ (the CLI also works from an installed wheel with explicit paths)."""
    return Path(__file__).resolve().parent.parent
