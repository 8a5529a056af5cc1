"""Errors raised for bad input: each names what is wrong and where (file, element, field)."""

from __future__ import annotations


class IdpError(Exception):
    """Base class of every error idp raises on purpose."""


class MeshError(IdpError):
    """A mesh file or mesh array is unusable (unreadable, non-manifold, inverted, NaN, ...)."""


class SceneError(IdpError):
    """A scene file or scene description is invalid; the message names the key path."""


class IntersectingInputError(IdpError):
    """The start state has intersecting surface primitives and preservation was not asked for."""


class CertificateError(IdpError):
    """An accepted frame failed the independent injectivity check (must never happen)."""


class SolverError(IdpError):
    """The nonlinear or linear solver could not continue (e.g. non-finite values)."""


class ResourceError(SolverError):
    """A run would need more memory than it may use (a step's estimated peak over the memory available or the
    ``solver.max_memory`` limit): raised before the factorisation that would allocate it. The CLI exits with the
    solver's code (4), as for a run that runs out of memory on its own."""


class FontError(IdpError):
    """A font file or a text to set in it is unusable (unreadable font, missing glyphs, empty text)."""


class OutputError(IdpError):
    """An output path is unusable: a file where a folder is needed, a folder where a file is, no permission."""


class MesherUnavailableError(IdpError):
    """An optional mesher (TetGen, through the ``idp[remesh]`` extra) is needed but not installed."""


class MissingDependencyError(IdpError):
    """An optional dependency a command needs is not installed (e.g. Dask for ``idp batch``: ``idp[batch]``)."""
