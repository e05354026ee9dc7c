"""Streaming point cloud writers: points arrive in chunks, the file is written as they come.

:class:`CloudWriter` is what :func:`treesim.io.open_cloud_writer` returns; each format
module subclasses it (``las.LasCloudWriter``, ``ply.PlyCloudWriter``,
``text.TextCloudWriter``) and the whole-cloud writers (``write_las``, ``write_ply``,
``write_text``) are one ``write`` between an open and a close, so each format has a single
implementation.

The writer declares its fields (names and dtypes) when it is opened; every chunk must
carry exactly those fields, and their values are cast to the declared dtypes. Output is
atomic (:class:`~treesim.io._common.AtomicFile`): the content goes to a temporary file
beside the destination, moved onto it by :meth:`CloudWriter.close`; :meth:`~CloudWriter.abort`,
an exception inside the ``with`` block, or any error raised by ``write`` or ``close``
removes the temporary file and leaves an existing destination untouched.
"""

from __future__ import annotations

import warnings
from abc import ABC, abstractmethod
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any, NoReturn

import numpy as np
from numpy.typing import DTypeLike

from ..errors import InvalidGeometryError, InvalidParameterError, TreesimError
from ._common import AtomicFile, check_field, write_error

__all__ = ["CloudWriter"]


class CloudWriter(ABC):
    """Write a point cloud file chunk by chunk; a context manager.

    Use through :func:`treesim.io.open_cloud_writer`::

        with open_cloud_writer("scan.laz", fields={"intensity": np.uint16}) as out:
            for points, fields in chunks:
                out.write(points, fields)

    Leaving the ``with`` block normally closes the writer (the file appears at its
    path); leaving it with an exception aborts it (nothing appears, an existing file is
    kept). Peak memory does not grow with the number of points written: each format
    holds at most a bounded buffer (see the format modules).

    Parameters
    ----------
    path : str or Path
        The destination file.
    fields : mapping of str -> dtype
        The per-point fields every chunk carries, in file order, and the dtype each is
        cast to before it is written.
    metadata : mapping, optional
        Describes the cloud as a whole (``Cloud.metadata``); formats that can, store it.

    Raises
    ------
    InvalidGeometryError
        If a field is named like a coordinate or its dtype is not numeric or boolean.

    Notes
    -----
    Subclasses implement ``_open`` (create the temporary file, write what they can of
    the header), ``_write`` (one non-empty chunk), ``_finish`` (flush, complete the
    header, close the file) and ``_discard`` (close the file without completing it), and
    extend ``_translate`` to map their libraries' exceptions to treesim's; they call
    :meth:`_start` at the end of their ``__init__``, once their own checks have passed.
    """

    def __init__(
        self,
        path: str | Path,
        fields: Mapping[str, DTypeLike],
        metadata: Mapping[str, Any] | None = None,
    ) -> None:
        self._path = Path(path)
        self._state = "new"
        declared: dict[str, np.dtype] = {}
        for name, dtype in fields.items():
            if not isinstance(name, str):
                raise InvalidParameterError(f"field names must be strings, got {name!r}")
            try:
                declared[name] = np.dtype(dtype)
            except TypeError as exc:
                raise InvalidParameterError(
                    f"field {name!r}: {dtype!r} is not a numpy dtype"
                ) from exc
            check_field(name, declared[name])
        self._fields = declared
        self._metadata: dict[str, Any] = dict(metadata or {})
        self._points_written = 0
        self._output: AtomicFile | None = None

    # -- public API -------------------------------------------------------------------

    @property
    def path(self) -> Path:
        """The destination file (it exists once the writer is closed)."""
        return self._path

    @property
    def fields(self) -> dict[str, np.dtype]:
        """The declared fields and their dtypes, in file order."""
        return dict(self._fields)

    @property
    def points_written(self) -> int:
        """How many points the writer has accepted so far."""
        return self._points_written

    @property
    def closed(self) -> bool:
        """Whether the writer was closed or aborted (it accepts no more points)."""
        return self._state != "open"

    def write(self, points: np.ndarray, fields: Mapping[str, np.ndarray] | None = None) -> None:
        """Append a chunk of points.

        Parameters
        ----------
        points : (n, 3) float64
            Coordinates; ``n`` may be 0.
        fields : mapping of str -> (n,) array, optional
            Exactly the declared fields (``None`` when none were declared); each is cast
            to its declared dtype.

        Raises
        ------
        InvalidParameterError
            If the writer is closed, or the chunk's field names differ from the declared.
        InvalidGeometryError
            If the shapes are wrong or the format cannot store the chunk (see the format
            modules).
        InputFormatError
            If the file cannot be written.

        Notes
        -----
        Any error aborts the writer (no partial file is left) before it propagates.
        """
        self._check_open()
        try:
            pts, columns = self._chunk(points, fields)
            if len(pts):
                self._write(pts, columns)
            self._points_written += len(pts)
        except BaseException as exc:
            self._fail(exc)

    def close(self) -> Path:
        """Complete the file and move it onto its path.

        Returns
        -------
        Path
            The path written. Closing a closed writer again returns it again.

        Raises
        ------
        InvalidParameterError
            If the writer was aborted.
        InputFormatError
            If the file cannot be completed or moved into place (nothing is left then).
        """
        if self._state == "closed":
            return self._path
        self._check_open()
        try:
            self._finish()
            assert self._output is not None
            self._output.commit()
        except BaseException as exc:
            self._fail(exc)
        self._state = "closed"
        return self._path

    def abort(self) -> None:
        """Give up: remove the temporary file; an existing destination is left untouched.

        Does nothing if the writer is already closed or aborted.
        """
        if self._state != "open":
            return
        self._state = "aborted"
        try:
            self._discard()
        finally:
            if self._output is not None:
                self._output.discard()

    def __enter__(self) -> CloudWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self._abort_quietly()

    def __del__(self) -> None:
        # A writer dropped while open never completes: remove its temporary file.
        if getattr(self, "_state", None) == "open":
            try:
                warnings.warn(
                    f"a CloudWriter for {self._path} was never closed; its output is discarded",
                    ResourceWarning,
                    stacklevel=1,
                )
            finally:
                self._abort_quietly()

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({str(self._path)!r}, {self._state}, "
            f"{self._points_written} points)"
        )

    # -- for subclasses ---------------------------------------------------------------

    def _start(self) -> None:
        """Create the temporary file through ``_open``; call at the end of ``__init__``."""
        output = AtomicFile(self._path)
        self._output = output
        self._state = "open"
        try:
            self._open(output.tmp)
        except BaseException as exc:
            self._fail(exc)

    @abstractmethod
    def _open(self, tmp: Path) -> None:
        """Open ``tmp`` for writing and write what is known of the header."""

    @abstractmethod
    def _write(self, points: np.ndarray, columns: dict[str, np.ndarray]) -> None:
        """Write one chunk: (n, 3) float64 points (n > 0), columns in the declared dtypes
        and order."""

    @abstractmethod
    def _finish(self) -> None:
        """Flush what is buffered, complete the header and close the file."""

    @abstractmethod
    def _discard(self) -> None:
        """Close the file without completing it (it is deleted next); should not raise."""

    def _translate(self, exc: BaseException) -> BaseException:
        """The treesim error to raise for ``exc`` (``exc`` itself if it needs no mapping)."""
        if isinstance(exc, OSError):
            return write_error(self._path, exc)
        return exc

    # -- internals --------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._state != "open":
            raise InvalidParameterError(
                f"the writer for {self._path} is {self._state}; open a new one to write again"
            )

    def _chunk(
        self, points: np.ndarray, fields: Mapping[str, np.ndarray] | None
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Check a chunk against the declaration; cast its fields to the declared dtypes."""
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InvalidGeometryError(f"points must have shape (n, 3), got {pts.shape}")
        given = dict(fields or {})
        if set(given) != set(self._fields):
            missing = [n for n in self._fields if n not in given]
            extra = sorted(set(given) - set(self._fields))
            raise InvalidParameterError(
                f"a chunk written to {self._path.name} must carry exactly the declared fields "
                f"{list(self._fields)}; missing {missing}, undeclared {extra}"
            )
        columns: dict[str, np.ndarray] = {}
        n = len(pts)
        for name, dtype in self._fields.items():
            values = np.asarray(given[name])
            if values.shape != (n,):
                raise InvalidGeometryError(
                    f"field {name!r} has shape {values.shape} for {n} points; expected ({n},)"
                )
            if values.dtype.kind not in "biuf":
                check_field(name, values.dtype)
            columns[name] = values.astype(dtype, copy=False)
        return pts, columns

    def _fail(self, exc: BaseException) -> NoReturn:
        """Abort, then raise ``exc`` mapped to a treesim error."""
        self._abort_quietly()
        mapped = exc if isinstance(exc, TreesimError) else self._translate(exc)
        if mapped is exc:
            raise exc
        raise mapped from exc

    def _abort_quietly(self) -> None:
        """Abort while another error propagates: a failure to clean up must not hide it."""
        try:
            self.abort()
        except Exception:  # noqa: BLE001 - the original error is the one to report
            pass
