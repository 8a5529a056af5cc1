"""Checks of input and output paths that never raise an OSError.

``Path.is_file()`` / ``is_dir()`` raise ``OSError`` for a path the system cannot even look up: a name longer than
the file system allows (ENAMETOOLONG) or a folder without search permission (EACCES). Input paths come from
users, scene files and the command line, so every reader checks them here and reports such a path as not
found, with the system's reason (:func:`why`). Output folders are checked before any work
(:func:`check_output_dir`: a file where the folder should be is an :class:`~idp.errors.OutputError`, not an
``OSError`` after the run) and created by :func:`make_output_dir`.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

from idp.errors import OutputError


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


def output_dir_problem(path: str | os.PathLike) -> str | None:
    """Why ``path`` cannot be (or become) an output folder, found without creating anything; None when it can.

    ``path`` must be a folder or not exist yet; its nearest existing ancestor must be a writable folder."""
    if "\x00" in os.fspath(path):  # Path.exists() just says False for it; mkdir would raise ValueError
        return "the name contains a NUL character"
    p = Path(path)
    for q in (p, *p.parents):
        try:
            if not (q.exists() or q.is_symlink()):
                continue
            if not q.is_dir():
                return "is a file, not a folder" if q == p else f"{q} is a file, not a folder"
        except (OSError, ValueError) as exc:
            return f"cannot look it up ({getattr(exc, 'strerror', None) or exc})"
        if not os.access(q, os.W_OK | os.X_OK):
            return f"no permission to write in {q}"
        return None
    return None


def check_output_dir(path: str | os.PathLike) -> Path:
    """``path`` as a Path; OutputError naming it when it cannot be an output folder (nothing is created)."""
    problem = output_dir_problem(path)
    if problem is not None:
        raise OutputError(f"output folder {path}: {problem}")
    return Path(path)


def make_output_dir(path: str | os.PathLike) -> Path:
    """Create the output folder ``path`` (and its parents); OutputError naming it when that is impossible."""
    p = check_output_dir(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except (OSError, ValueError) as exc:
        raise OutputError(f"cannot create output folder {p}: {getattr(exc, 'strerror', None) or exc}") from None
    return p
