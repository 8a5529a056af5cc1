"""Checks of input paths that never raise.

``Path.is_file()`` / ``is_dir()`` raise ``OSError`` for a path the system cannot even look up: a name longer than
the file system allows (ENAMETOOLONG) or a folder without search permission (EACCES). Input paths come from
users, scene files and the command line, so every reader checks them here and reports such a path as not
found, with the system's reason (:func:`why`).
"""

from __future__ import annotations

import errno
import os
from pathlib import Path


def _stat_error(path: str | os.PathLike) -> OSError | None:
    try:
        os.stat(path)
    except OSError as exc:
        return exc
    except ValueError:  # an embedded NUL byte
        return OSError(0, "invalid path (NUL byte)")
    return None


def is_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a regular file (following links); False when it cannot be looked up."""
    try:
        return Path(path).is_file()
    except (OSError, ValueError):
        return False


def is_dir(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a folder (following links); False when it cannot be looked up."""
    try:
        return Path(path).is_dir()
    except (OSError, ValueError):
        return False


def why(path: str | os.PathLike) -> str:
    """``" (File name too long)"``: why ``path`` cannot be looked up, or "" when it is simply absent (or there)."""
    exc = _stat_error(path)
    if exc is None or exc.errno in (errno.ENOENT, errno.ENOTDIR):  # plainly not there
        return ""
    return f" ({exc.strerror or exc})"
