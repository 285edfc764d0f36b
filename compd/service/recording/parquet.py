"""Parquet recorder: the CSV recorder's rows, named, rotated and budgeted alike, as Parquet.

A fleet's recordings are copied off many edge PCs and read by pandas,
pyarrow, Spark or DuckDB; Parquet is typed, compressed (a 1 Hz day of 40
signals is a few MB instead of tens) and carries key-value metadata in its
footer: ``machine_id``, ``compd_version``, ``model``, ``model_sha256``,
``config``, the run's marks and the columns' units, as the CSV recorder's
comment lines do. Whole numbers (status word, heartbeat, health) are int64
columns, other numbers float64 to 15 significant digits.

**Crash safety.** A Parquet file is readable only once its footer is written,
so a file left open by a SIGKILL or a power cut would be lost whole. This
recorder therefore never leaves a file without its footer: rows are gathered
in memory, and every ``flush_every_rows`` rows (default 60: one minute at
1 Hz) the open file is written again, whole, footer included, to
``<name>.tmp`` and renamed over ``<name>`` (``rename(2)`` is atomic). Every
``compd-*.parquet`` on disk is therefore a complete file up to its last
write. The write runs on the recorder's own thread, so the tick does not
wait for the disk; a crash loses the rows gathered since the last completed
write: fewer than ``flush_every_rows`` (59 at the default) once it is done,
fewer than twice that while one is in progress (a write takes milliseconds
to a few hundred). A ``.tmp`` left by a crash during a write is deleted when
the next file opens.

Writing the open file again costs time in proportion to its length, so its
length is bounded like the CSV recorder's: ``max_file_age_s`` and
``max_file_bytes`` rotate it (the bytes counted are those of the last
write). An hour at 1 Hz (3,600 rows, one row group) is a good file length;
the default ``max_file_age_s`` of 86,400 s makes each minute's write take
up to a day of rows (``benchmarks/bench_recorder_parquet.py`` has the
figures). The open file's rows stay in memory as Arrow arrays (8 bytes a cell).

**A disk that refuses.** A failed write (a full disk) is one fault: every
row raises :class:`~compd.errors.RecorderError` until a write succeeds again,
so the daemon logs one episode, not one per minute. The rows are kept
meanwhile, up to ``max_unwritten_rows``, and the file is not rotated; the
write is tried again after :data:`RETRY_FIRST_S`, then twice as long each
time up to :data:`RETRY_MAX_S` (the rows' clock). Rows beyond the bound, and
the rows of a file that had to be closed while failing, are lost and
counted (:meth:`take_lost_rows`, told once when recording works again).
Each write is synced (the ``.tmp``, then its directory after the rename),
so a power cut leaves the old file or the new one.

pyarrow is imported when the first file is written, so a daemon recording
CSV never loads it.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

from compd.errors import RecorderError
from compd.service.recording.csvline import Cell
from compd.service.recording.marks import tidy_array
from compd.service.recording.recorder import (
    TIME_COLUMN,
    RecordingFiles,
    check_columns,
    delete_oldest,
    error,
    sync_directory,
)

log = logging.getLogger(__name__)

SUFFIX = "parquet"
#: Rows per rewrite of the open file unless the config says otherwise: a crash loses fewer.
DEFAULT_FLUSH_EVERY_ROWS = 60
#: Rows per row group: an hour at 1 Hz, so a reader can take a long file an hour at a time.
ROW_GROUP_ROWS = 3600
#: Rows kept unwritten while writes fail (an hour at 1 Hz): beyond, new rows are lost, counted.
DEFAULT_MAX_UNWRITTEN_ROWS = 3600
#: The first wait (s) before a failed write is tried again; doubled after each failure, up to:
RETRY_FIRST_S = 10.0
RETRY_MAX_S = 300.0


class ParquetRecorder(RecordingFiles):
    """Write rows to rotating Parquet files in ``directory``.

    The parameters are :class:`~compd.service.recording.recorder.Recorder`'s;
    ``flush_every_rows`` is the row group's size and the most rows a crash loses;
    ``max_unwritten_rows`` the most rows kept while writes fail.
    """

    def __init__(
        self,
        directory: Path,
        *,
        max_file_bytes: int,
        max_file_age_s: float,
        max_total_bytes: int,
        flush_every_rows: int = DEFAULT_FLUSH_EVERY_ROWS,
        clock: Callable[[], float] = time.time,
        metadata: Mapping[str, str] | None = None,
        max_unwritten_rows: int = DEFAULT_MAX_UNWRITTEN_ROWS,
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
        self._text: frozenset[str] = frozenset()  # columns whose first value was text
        self._ints: frozenset[str] = frozenset()  # columns whose first value was a whole number
        self._size = 0  # bytes of the open file at its last write
        self._groups: list[Any] = []  # the open file's row groups (pyarrow.RecordBatch)
        self._times_s: list[float] = []
        self._rows: list[list[Cell]] = []
        self._file_metadata: dict[str, str] = {}
        self._worker: ThreadPoolExecutor | None = None
        self._writing: Future[int] | None = None
        self.max_unwritten_rows = max_unwritten_rows
        self._grouped_rows = 0  # rows of the open file in its batches (self._groups)
        self._durable_rows = 0  # of those, the rows its last completed write holds
        self._writing_rows = 0  # the rows the write in progress holds
        #: The failure of the writes, until one succeeds again: raised by every row meanwhile.
        self._failure: RecorderError | None = None
        self._backoff_s = RETRY_FIRST_S
        self._retry_at_s = -math.inf

    def record_values(
        self, columns: tuple[str, ...], values: Sequence[Cell], *, at_s: float | None = None
    ) -> None:
        """:meth:`record` of the row ``dict(zip(columns, values))`` (as the CSV recorder's)."""
        self.record(dict(zip(columns, values, strict=True)), at_s=at_s)

    def record(self, row: Mapping[str, Cell], *, at_s: float | None = None) -> None:
        """Append one row stamped ``at_s`` (s since the epoch, default the clock's now).

        A column whose first value is an ``int`` (or bool) is stored as int64 (a
        later value that is not a whole number as null, a gap), other numbers as
        float64 (NaN a gap), a column whose first value is text as strings. Raises
        :class:`~compd.errors.RecorderError` when the files cannot be written.
        """
        now_s = self._clock() if at_s is None else at_s
        if tuple(row) != self._columns or self._metadata_changed:
            columns = check_columns(row)
            self.close()  # one schema and one model per file
            self._columns = columns
            self._text = frozenset(k for k, v in row.items() if isinstance(v, str))
            self._ints = frozenset(k for k, v in row.items() if isinstance(v, int))
            self._metadata_changed = False
        self._collect(block=False)
        if (
            self._path is None
            or now_s <= self._last_s  # the clock stepped back: times must increase in a file
            or (  # not while writes fail: the rows wait in the open file
                self._failure is None
                and (
                    self._size > self.max_file_bytes
                    or now_s - self._opened_s >= self.max_file_age_s
                )
            )
        ):
            self._open(now_s)
        self._last_s = now_s
        if self._grouped_rows + len(self._rows) - self._durable_rows < self.max_unwritten_rows:
            self._times_s.append(now_s)
            self._rows.append([row[name] for name in self._columns])
        else:
            self.lost_rows += 1
        if len(self._rows) >= self.flush_every_rows or (
            self._failure is not None and now_s >= self._retry_at_s
        ):
            self.flush()
        if self._failure is not None:
            raise self._failure

    def flush(self) -> None:
        """Make the gathered rows a batch and have the open file written again, whole.

        The write runs on the recorder's own thread (pyarrow releases the
        GIL), so the tick that gathered the rows does not wait for the disk;
        the next flush waits for it first. After a failed write the next one
        waits for its retry time (:data:`RETRY_FIRST_S`, doubling).
        """
        if self._path is None:
            return
        if self._rows:
            self._groups.append(self._batch())
            self._grouped_rows += len(self._rows)
            self._times_s, self._rows = [], []
        self._collect(block=True)
        if self._grouped_rows == self._durable_rows:
            return  # all written
        if self._failure is not None and self._last_s < self._retry_at_s:
            return  # the retry is not due
        if self._worker is None:
            self._worker = ThreadPoolExecutor(1, thread_name_prefix="compd-recorder")
        self._writing_rows = self._grouped_rows
        self._writing = self._worker.submit(
            _write_file, self._path, list(self._groups), dict(self._file_metadata)
        )

    def close(self) -> None:
        """Write what is gathered (a last try, even while failing), wait, close; the next row opens a new file.

        Raises RecorderError if that write failed: the file's unwritten rows are lost (counted).
        """
        try:
            self._retry_at_s = -math.inf
            self.flush()
            self._collect(block=True)
            if self._failure is not None and self._path is not None:
                self.lost_rows += self._grouped_rows - self._durable_rows
                raise self._failure
        finally:
            self._close_file()

    def _open(self, now_s: float) -> None:
        self.close()
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            _remove_leftovers(self.directory)
            # The name only: the first flush writes the file, so a crash before it leaves none.
            path, fd = self.create(now_s, SUFFIX)
            os.close(fd)
            path.unlink()
        except OSError as exc:
            raise error(f"cannot create a recording in {self.directory}", exc) from exc
        self._path, self._opened_s, self._size = path, now_s, 0
        self._file_metadata = self.file_metadata(path, now_s)  # as at its first row, to its last
        delete_oldest(self.directory, path, self.max_file_bytes, self.max_total_bytes)

    def _collect(self, *, block: bool) -> None:
        """The result of the write in progress once it is done (``block``: wait for it)."""
        writing = self._writing
        if writing is None or (not block and not writing.done()):
            return
        self._writing = None
        try:
            self._size = writing.result()
        except OSError as exc:
            first = self._failure is None
            self._backoff_s = RETRY_FIRST_S if first else min(2 * self._backoff_s, RETRY_MAX_S)
            self._retry_at_s = self._last_s + self._backoff_s
            self._failure = RecorderError(
                f"cannot write to {self._path}: {exc.strerror or exc}; tried again in "
                f"{self._backoff_s:g} s, up to {self.max_unwritten_rows} rows kept meanwhile"
            )
        else:
            self._durable_rows = self._writing_rows
            if self._failure is not None:
                log.info("recording written again to %s", self._path)
            self._failure, self._backoff_s = None, RETRY_FIRST_S

    def _close_file(self) -> None:
        if self._writing is not None:  # closing after an error: let the write finish, quietly
            with contextlib.suppress(OSError):
                self._writing.result()
            self._writing = None
        self._path = None
        self._groups, self._times_s, self._rows = [], [], []
        self._grouped_rows = self._durable_rows = self._writing_rows = 0

    def _batch(self) -> Any:
        import pyarrow as pa

        arrays = [pa.array([round(t * 1000) for t in self._times_s], pa.timestamp("ms", "UTC"))]
        other = self._text | self._ints
        floats = [i for i, name in enumerate(self._columns) if name not in other]
        # All float columns tidied at once: numpy's work per call outweighs its work per value.
        tidied = tidy_array([[_number(row[i]) for i in floats] for row in self._rows])
        for i, name in enumerate(self._columns):
            cells = [row[i] for row in self._rows]
            if name in self._text:
                arrays.append(pa.array([str(c) for c in cells], pa.string()))
            elif name in self._ints:
                arrays.append(pa.array([_whole(c) for c in cells], pa.int64()))
            else:
                arrays.append(pa.array(tidied[:, floats.index(i)], pa.float64()))
        return pa.RecordBatch.from_arrays(arrays, names=[TIME_COLUMN, *self._columns])


def _write_file(path: Path, batches: list[Any], metadata: dict[str, str]) -> int:
    """Write ``batches`` to ``path`` as a whole Parquet file, atomically; its size in bytes.

    Row groups of up to :data:`ROW_GROUP_ROWS` rows: a row group per flush
    (60 rows) made files 3x larger and 6x slower to write.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_batches(batches).replace_schema_metadata(metadata)
    temporary = path.with_name(path.name + ".tmp")
    try:
        pq.write_table(table, temporary, compression="zstd", row_group_size=ROW_GROUP_ROWS)
        fd = os.open(temporary, os.O_RDONLY)
        try:
            os.fsync(fd)  # the bytes on disk before the name points at them: a power cut
        finally:
            os.close(fd)
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise
    sync_directory(path.parent)  # and the rename itself
    return path.stat().st_size


def _number(cell: Cell) -> float:
    try:
        return float(cell)
    except ValueError:  # text in a numeric column: a gap, as the loader reads unreadable cells
        return math.nan


def _whole(cell: Cell) -> int | None:
    """A cell of a whole-number column; None (null, a gap) for anything else."""
    if isinstance(cell, int):
        return int(cell)
    number = _number(cell)
    return int(number) if math.isfinite(number) and number == int(number) else None


def _remove_leftovers(directory: Path) -> None:
    """Delete the ``.tmp`` a crash during a write left (its file holds the rows up to the flush before)."""
    for leftover in directory.glob(f"compd-*.{SUFFIX}.tmp"):
        log.info("removing %s, left by a crash during a write", leftover)
        with contextlib.suppress(OSError):
            leftover.unlink()


__all__ = ["DEFAULT_FLUSH_EVERY_ROWS", "ParquetRecorder", "RecorderError"]
