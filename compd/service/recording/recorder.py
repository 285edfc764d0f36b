"""Recorder: the service's signals and offsets, one CSV row per tick, in rotating files.

(``recorder.format: parquet`` writes Parquet instead: :mod:`compd.service.recording.parquet`,
which shares this module's naming, rotation and disk budget.)

What the loop read and wrote is the evidence for every later question (did
the model drift? what did the machine see when the part was out of
tolerance?), and it is the input of ``compd compare`` and re-identification.
So the files are exactly what :func:`compd.files.data.load_data` reads: a header,
a ``timestamp`` column first with UTC ISO-8601 times carrying their offset
(``2026-11-23T10:15:00.000+00:00``), then one column per key of the row.
Before the header, ``# key: value`` comment lines say where the rows come
from: ``machine_id`` (the config's top-level ``machine_id``), ``compd_version``,
``model`` and ``model_sha256`` (the active model), ``config`` (its path).
The loader reads them into :attr:`compd.files.data.DataSet.metadata`.
Each file also says which run it belongs to (``run_id``, one per daemon
start; ``run_file``, its number in the run; ``run_previous``, the file before
it; ``run_reason``, why it was started; ``run_gap_s``, the time since the
previous file's last row) and each column's unit (``unit.<column>``):
:mod:`compd.service.recording.marks`, read back by :mod:`compd.files.runs`,
which joins a run's files into one record again.

Files are named by the machine and their first row's UTC time
(``compd-mill-a-20261123T101500Z.csv``; ``compd-20261123T101500Z.csv`` without a
``machine_id``), so a central store of many machines' files has no collisions,
and rotated when they reach ``max_file_bytes`` or ``max_file_age_s``, when
the row's keys change (a new model with other outputs: a file has one
header) or the active model changes (a file names one model), and when
the time does not increase (the clock was set back: the loader refuses
times that go backwards). The oldest files are deleted so that the directory never holds more
than ``max_total_bytes`` of recordings, the open file included: an edge PC's
disk must not fill up over months of unattended running. Only files with
this naming pattern are ever deleted.

Every row is written to the file with one ``write(2)`` of whole lines (every
``flush_every_rows`` rows; default each row), so a crash loses at most the
unwritten rows and a file never ends in half a row: when a write fails part
way (disk full), the file is truncated back to its last complete line. OS
errors become :class:`~compd.errors.RecorderError`, which the loop logs
while it keeps compensating. A row costs a few microseconds (one timestamp,
one join, one system call).
"""

from __future__ import annotations

import logging
import math
import os
import re
import time
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Self

from compd.errors import RecorderError
from compd.files.columns import TIME_NAMES
from compd.service.recording.csvline import Cell, LineFormats, Stamps, cell
from compd.service.recording.marks import RunMarks

log = logging.getLogger(__name__)

TIME_COLUMN = "timestamp"
PREFIX = "compd"
#: A recording's name: its machine (if named), its first row's UTC time, a number within that second, the format.
NAME = re.compile(
    rf"^{PREFIX}-(?:(?P<machine>[A-Za-z0-9._-]+)-)?(?P<time>\d{{8}}T\d{{6}}Z)"
    r"(?:-(?P<number>\d+))?\.(?P<format>csv|parquet)$"
)
#: A machine_id that may name files (the config's pattern): others are left out of the name.
_MACHINE = re.compile(r"[A-Za-z0-9._-]{1,64}")


class RecordingFiles:
    """What both recorders share: the folder, the rotation limits, the clock, the files' metadata.

    Parameters
    ----------
    directory:
        Created on the first row if missing.
    max_file_bytes:
        A file is closed before a row would take it past this size (a single
        row larger than this still gets a file of its own).
    max_file_age_s:
        A file is closed before a row written this long (s) after its first row.
    max_total_bytes:
        Recordings in ``directory`` (closed files plus the open file's limit,
        ``max_file_bytes``) are kept under this by deleting the oldest files.
    flush_every_rows:
        Rows gathered before they are written (the most a crash loses).
    clock:
        Seconds since the epoch, UTC (``time.time``); tests pass a fake.
    metadata:
        ``key: value`` pairs stored in every file (see the module docstring);
        its ``machine_id`` also names the files.
    """

    def __init__(
        self,
        directory: Path,
        *,
        max_file_bytes: int,
        max_file_age_s: float,
        max_total_bytes: int,
        flush_every_rows: int,
        clock: Callable[[], float] = time.time,
        metadata: Mapping[str, str] | None = None,
    ) -> None:
        check_limits(max_file_bytes, max_file_age_s, max_total_bytes, flush_every_rows)
        self.directory = Path(directory)
        self.max_file_bytes = max_file_bytes
        self.max_file_age_s = max_file_age_s
        self.max_total_bytes = max_total_bytes
        self.flush_every_rows = flush_every_rows
        self.metadata: dict[str, str] = dict(metadata or {})
        self._clock = clock
        self._columns: tuple[str, ...] = ()
        self._path: Path | None = None
        self._opened_s = 0.0
        self._last_s = -math.inf
        self._metadata_changed = False
        #: The run these files belong to (one per recorder: one per daemon start); its
        #: ``units`` name each column's unit in the files.
        self.run = RunMarks()
        #: Rows lost to failed writes since :meth:`take_lost_rows` last took them.
        self.lost_rows = 0

    def take_lost_rows(self) -> int:
        """The rows lost since the last call (told once, when recording works again)."""
        lost, self.lost_rows = self.lost_rows, 0
        return lost

    def set_model(self, name: str, sha256: str) -> None:
        """Name the active model in the files; a change starts a new file at the next row."""
        if set_model(self.metadata, name, sha256):
            self._metadata_changed = True
            self.run.why = "model"

    def create(self, now_s: float, suffix: str) -> tuple[Path, int]:
        """A new file in the folder for a first row at ``now_s`` (:func:`create`, with the machine)."""
        return create(self.directory, now_s, suffix, self.metadata.get("machine_id"))

    def file_metadata(self, path: Path, now_s: float) -> dict[str, str]:
        """What the new file ``path`` says about itself: the metadata, its run, its columns' units."""
        return self.run.file_metadata(
            self.metadata, path, self._columns, now_s=now_s, last_s=self._last_s
        )

    @property
    def path(self) -> Path | None:
        """The file being written, or None before the first row and after :meth:`close`."""
        return self._path

    def reopen(self) -> Path | None:
        """Close the file being written (SIGHUP): the next row starts a new one of the same run.

        Its ``run_reason`` is ``reopened``. Returns the file closed (None if
        none was open); raises RecorderError as :meth:`close` does.
        """
        closed = self._path
        try:
            self.close()
        finally:
            self.run.why = "reopened"
        return closed

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class Recorder(RecordingFiles):
    """Write rows to rotating CSV files in ``directory`` (parameters: :class:`RecordingFiles`;
    ``flush_every_rows`` defaults to 1, which loses nothing but the row being written on a crash)."""

    def __init__(
        self,
        directory: Path,
        *,
        max_file_bytes: int,
        max_file_age_s: float,
        max_total_bytes: int,
        flush_every_rows: int = 1,
        clock: Callable[[], float] = time.time,
        metadata: Mapping[str, str] | None = None,
    ) -> None:
        super().__init__(
            directory,
            max_file_bytes=max_file_bytes,
            max_file_age_s=max_file_age_s,
            max_total_bytes=max_total_bytes,
            flush_every_rows=flush_every_rows,
            clock=clock,
            metadata=metadata,
        )
        self._fd: int | None = None
        self._size = 0  # bytes of the open file, pending lines included
        self._written = 0  # bytes of complete lines known to be in the open file
        self._pending: list[bytes] = []
        self._rows_in_file = 0
        self._stamps = Stamps()
        self._lines = LineFormats()

    @property
    def columns(self) -> tuple[str, ...]:
        """The open file's columns after ``timestamp``, in order."""
        return self._columns

    def record(self, row: Mapping[str, Cell], *, at_s: float | None = None) -> None:
        """Append one row, stamped ``at_s`` (s since the epoch, default the clock's now).

        Cells are written as ``str(value)``, floats to 15 significant digits
        (``%.15g``: ``21.15``, ``20``; :func:`~compd.service.recording.marks.tidy`
        says why), bools as 1/0, NaN as ``nan`` (a gap to
        :func:`~compd.files.data.load_data`), text quoted when it holds a comma,
        quote or newline (:mod:`compd.service.recording.csvline`). Raises
        :class:`~compd.errors.RecorderError` when the files cannot be written.
        """
        try:
            values = [row[name] for name in self._columns]
            same = len(row) == len(values)
        except KeyError:
            same = False
        if not same or not values or self._metadata_changed:
            self._start_columns(row)
            values = [row[name] for name in self._columns]
        self._append(values, self._clock() if at_s is None else at_s)

    def record_values(
        self, columns: tuple[str, ...], values: Sequence[Cell], *, at_s: float | None = None
    ) -> None:
        """:meth:`record` of the row ``dict(zip(columns, values))`` (distinct ``columns``), without
        the dict: the loop's row, whose columns stay the same tuple tick after tick."""
        if (columns is not self._columns and columns != self._columns) or self._metadata_changed:
            self._start_columns(dict(zip(columns, values, strict=True)))
            if len(self._columns) != len(columns):
                raise RecorderError(f"a row's columns are not distinct: {columns}")
        self._append(values, self._clock() if at_s is None else at_s)

    def _append(self, values: Sequence[Cell], now_s: float) -> None:
        line = self._lines.line(self._stamps(now_s), values).encode()
        if self._fd is None or (
            self._rows_in_file
            and (
                self._size + len(line) > self.max_file_bytes
                or now_s - self._opened_s >= self.max_file_age_s
                or now_s <= self._last_s  # the clock stepped back: times must increase in a file
            )
        ):
            self._open(now_s)
        self._last_s = now_s
        self._pending.append(line)
        self._size += len(line)
        self._rows_in_file += 1
        if len(self._pending) >= self.flush_every_rows:
            self.flush()

    def flush(self) -> None:
        """Write the gathered rows now, as whole lines, or none of them."""
        if not self._pending or self._fd is None:
            return
        data = self._pending[0] if len(self._pending) == 1 else b"".join(self._pending)
        rows = len(self._pending) - (self._written == 0)  # the header is no row
        self._pending.clear()
        try:
            _write_all(self._fd, data)
        except OSError as exc:
            self.lost_rows += rows
            path = self._path
            self._abandon()
            raise error(f"cannot write to {path}", exc) from exc
        self._written += len(data)

    def close(self) -> None:
        """Write what is gathered, sync and close the file; the next row opens a new one."""
        try:
            self.flush()
        finally:
            self._close_file()

    def _start_columns(self, row: Mapping[str, Cell]) -> None:
        columns = check_columns(row)
        self.close()  # a file has one header and one model: new columns, new file
        self._columns = columns
        self._metadata_changed = False

    def _open(self, now_s: float) -> None:
        self.close()
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            path, fd = self.create(now_s, "csv")
        except OSError as exc:
            raise error(f"cannot create a recording in {self.directory}", exc) from exc
        self._fd, self._path, self._opened_s = fd, path, now_s
        self._rows_in_file = 0
        comments = "".join(
            f"# {key}: {' '.join(value.split())}\n"
            for key, value in self.file_metadata(path, now_s).items()
        )
        header = comments + ",".join(map(cell, (TIME_COLUMN, *self._columns))) + "\n"
        self._pending = [header.encode()]
        self._size = len(self._pending[0])
        self._written = 0
        delete_oldest(self.directory, path, self.max_file_bytes, self.max_total_bytes)

    def _close_file(self) -> None:
        if self._fd is None:
            return
        fd, self._fd, self._path = self._fd, None, None
        self._pending.clear()
        try:
            os.fsync(fd)  # on rotation only: rows survive a power cut without wearing the disk
        except OSError as exc:
            log.debug("cannot sync a recording: %s", exc)
        finally:
            os.close(fd)

    def _abandon(self) -> None:
        """After a failed write: cut the file back to its last whole line and close it.

        The next row starts a new file (with its header), so recording
        resumes by itself once the disk has room again.
        """
        assert self._fd is not None and self._path is not None
        path, written = self._path, self._written
        try:
            if written:
                os.ftruncate(self._fd, written)
        except OSError as exc:  # the half line stays; load_data would name its line
            log.debug("cannot truncate %s after a failed write: %s", path, exc)
        self._close_file()
        self.run.why = "resumed"
        if not written:  # not even the header made it: leave no empty file behind
            try:
                path.unlink()
            except OSError as exc:
                log.debug("cannot remove the empty recording %s: %s", path, exc)


def check_limits(
    max_file_bytes: int, max_file_age_s: float, max_total_bytes: int, flush_every_rows: int
) -> None:
    """Refuse rotation limits no recorder can keep (the config schema checks them first)."""
    if max_file_bytes <= 0 or max_file_age_s <= 0 or flush_every_rows < 1:
        raise ValueError(
            "max_file_bytes and max_file_age_s must be above 0, flush_every_rows at least 1"
        )
    if max_total_bytes < max_file_bytes:
        raise ValueError(
            f"max_total_bytes ({max_total_bytes}) must be at least "
            f"max_file_bytes ({max_file_bytes}): the open file alone may reach that size"
        )


def set_model(metadata: dict[str, str], name: str, sha256: str) -> bool:
    """Put the active model into ``metadata``; True if that changed it."""
    if metadata.get("model") == name and metadata.get("model_sha256") == sha256:
        return False
    metadata["model"], metadata["model_sha256"] = name, sha256
    return True


def check_columns(row: Mapping[str, Cell]) -> tuple[str, ...]:
    """The row's keys, refused if there are none or one would be read as the time column."""
    columns = tuple(row)
    if not columns:
        raise RecorderError("cannot record an empty row: a data file needs a signal column")
    clash = [name for name in columns if name in TIME_NAMES]
    if clash:
        raise RecorderError(
            f"cannot record a signal named {clash[0]!r}: "
            f"{', '.join(TIME_NAMES)} name the time column of a data file. "
            "Rename the signal in the configuration"
        )
    return columns


def delete_oldest(
    directory: Path, open_path: Path | None, max_file_bytes: int, max_total_bytes: int
) -> None:
    """Delete the oldest recordings until closed files plus one full file fit the budget.

    Only files named like a recording (:data:`NAME`, either format) count and are deleted.
    """
    try:
        found = [
            (_order(match), entry.path, entry.stat().st_size)
            for entry in os.scandir(directory)
            if (match := NAME.match(entry.name)) and entry.path != str(open_path)
        ]
    except OSError as exc:
        raise error(f"cannot list the recordings in {directory}", exc) from exc
    found.sort()
    total = sum(size for _, _, size in found) + max_file_bytes
    for _, path, size in found:
        if total <= max_total_bytes:
            break
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise error(f"cannot delete the old recording {path}", exc) from exc
        total -= size
        log.info("deleted the oldest recording %s (%d bytes) to stay under the limit", path, size)


def create(
    directory: Path, now_s: float, suffix: str, machine_id: str | None = None
) -> tuple[Path, int]:
    """A new file ``compd-[<machine_id>-]<UTC time>.<suffix>`` named by ``now_s``.

    ``-1``, ``-2``... follow the time if that second is taken.
    """
    machine = f"{machine_id}-" if machine_id and _MACHINE.fullmatch(machine_id) else ""
    stem = f"{PREFIX}-{machine}{datetime.fromtimestamp(now_s, UTC):%Y%m%dT%H%M%SZ}"
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND | os.O_CLOEXEC
    for n in range(1000):
        path = directory / (f"{stem}.{suffix}" if n == 0 else f"{stem}-{n}.{suffix}")
        try:
            return path, os.open(path, flags, 0o644)
        except FileExistsError:
            continue
    raise FileExistsError(f"{directory / stem}-*.{suffix}: 1000 files in one second")


def _order(match: re.Match[str]) -> tuple[str, int]:
    """Sort key of a recording's name: start time, then sequence number within the second."""
    return match["time"], int(match["number"] or 0)


def _write_all(fd: int, data: bytes) -> None:
    written = os.write(fd, data)
    if written < len(data):  # a short write (a signal, a full disk): the rest, until done or raised
        view = memoryview(data)[written:]
        while view:
            view = view[os.write(fd, view) :]


def sync_directory(directory: Path) -> None:
    """``fsync`` a directory: a file created or renamed in it survives a power cut."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def error(what: str, exc: OSError) -> RecorderError:
    return RecorderError(f"{what}: {exc.strerror or exc}; recording is paused until it succeeds")
