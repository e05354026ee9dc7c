"""treesim's exceptions: one base, flat subclasses grouped by cause.

Every error treesim raises on purpose is a :class:`TreesimError`; its message says
what was wrong and what to do about it. Third-party exceptions are mapped into these
at the boundary, so callers (the CLI, the service) need to catch only the base.
"""

from __future__ import annotations


class TreesimError(Exception):
    """Base class of every error treesim raises on purpose.

    Examples
    --------
    >>> import treesim as ts
    >>> try:
    ...     ts.run_preset("quick")
    ... except ts.TreesimError as err:
    ...     print(err)
    unknown preset 'quick'; the run presets are draft, standard, fine
    """


class InputFormatError(TreesimError):
    """A file could not be read: unknown suffix, corrupt content, or a missing file."""


class UnsupportedFormatError(InputFormatError):
    """A file's bytes are none of the formats treesim reads (known by content, not name)."""


class EmptyInputError(TreesimError):
    """The input holds no usable geometry (no points, no faces)."""


class InvalidGeometryError(TreesimError):
    """The input geometry is unusable: NaN or infinite coordinates, degenerate shape."""


class InvalidParameterError(TreesimError, ValueError):
    """A parameter is out of its valid range or inconsistent with another."""


class ScanError(TreesimError):
    """The virtual scan cannot run as asked (e.g. a station inside the geometry)."""


class ResourceLimitError(TreesimError):
    """The work asked for would exceed a configured limit (rays, memory, time)."""


class ReconstructionError(TreesimError):
    """Reconstruction of a tree model from a point cloud failed."""


class ModelError(TreesimError):
    """A tree model or cylinder table is invalid (bad rows, cycles, negative radii)."""
