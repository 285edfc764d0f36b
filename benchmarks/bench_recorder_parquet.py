"""Cost of the Parquet recorder's flush beside the CSV recorder writing the same rows.

The Parquet recorder keeps every file readable after a crash by writing the
open file again, whole, footer included, every ``flush_every_rows`` rows
(:mod:`compd.service.recording.parquet`), on its own thread. Two figures per
file length (10 min, 1 h, 1 day at 1 Hz, 40 signals and the status: what a
service with 6 inputs, 3 axes and their sub-models records):

- the tick's stall: the time ``record`` takes on the row that flushes
  (the 60 rows made into Arrow arrays and the write handed to the thread);
- the write: the thread's time to write the whole open file again (CPU of
  one core once a minute).

Baseline: the CSV recorder's time for the same 60 rows (one write per row),
and both formats' bytes per row.

Targets: the stall under 5 ms (the tick's p99 lateness target); writing an
hour's file under 100 ms (0.2 % of one core at one flush a minute).
Run: ``PYTHONPATH=. python benchmarks/bench_recorder_parquet.py`` from the repository root.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

from common import environment, verdict

from compd.service.recording.parquet import ParquetRecorder, _write_file
from compd.service.recording.recorder import Recorder

SIGNALS = 40
FLUSH_ROWS = 60
T0_S = 1_795_428_900.0
MAX_STALL_MS = 5.0
MAX_HOUR_WRITE_MS = 100.0
LIMITS = {"max_file_bytes": 1 << 34, "max_file_age_s": 1e9, "max_total_bytes": 1 << 36}


def row(k: int) -> dict[str, float | int | str]:
    cells: dict[str, float | int | str] = {
        f"s{i}": 20.0 + 0.001 * k * (i + 1) for i in range(SIGNALS)
    }
    cells["status"] = k % 4
    return cells


def parquet_ms(directory: Path, rows: int) -> tuple[float, float, int]:
    """Median stall and write (ms) over the last five flushes of a file of ``rows`` rows; its bytes."""
    recorder = ParquetRecorder(directory, flush_every_rows=FLUSH_ROWS, **LIMITS)  # type: ignore[arg-type]
    stalls, writes = [], []
    for k in range(rows):
        last_flushes = (k + 1) % FLUSH_ROWS == 0 and k + 1 > rows - 5 * FLUSH_ROWS
        if last_flushes:
            recorder._wait()  # the previous write is done, as a minute later it is
        started = time.perf_counter()
        recorder.record(row(k), at_s=T0_S + k)
        if last_flushes:
            stalls.append((time.perf_counter() - started) * 1e3)
            recorder._wait()
            assert recorder.path is not None
            started = time.perf_counter()
            _write_file(recorder.path, recorder._groups, {"machine_id": "bench"})
            writes.append((time.perf_counter() - started) * 1e3)
    assert recorder.path is not None
    size = recorder.path.stat().st_size
    recorder.close()
    return statistics.median(stalls), statistics.median(writes), size


def csv_ms(directory: Path) -> tuple[float, int]:
    """Time (ms) the CSV recorder takes for FLUSH_ROWS rows, and its bytes per row."""
    recorder = Recorder(directory, **LIMITS)  # type: ignore[arg-type]
    for k in range(600):
        recorder.record(row(k), at_s=T0_S + k)
    started = time.perf_counter()
    for k in range(600, 600 + FLUSH_ROWS):
        recorder.record(row(k), at_s=T0_S + k)
    elapsed = (time.perf_counter() - started) * 1e3
    assert recorder.path is not None
    size = recorder.path.stat().st_size
    recorder.close()
    return elapsed, size // (600 + FLUSH_ROWS)


def main() -> int:
    print(environment())
    with tempfile.TemporaryDirectory() as folder:
        base_ms, csv_bytes = csv_ms(Path(folder) / "csv")
        print(f"baseline: CSV recorder, {FLUSH_ROWS} rows of {SIGNALS + 1} signals: "
              f"{base_ms:.2f} ms, {csv_bytes} bytes per row")  # fmt: skip
        figures = {}
        for label, rows in (("10 min", 600), ("1 h", 3600), ("1 day", 86_400)):
            stall, write, size = parquet_ms(Path(folder) / label.replace(" ", ""), rows)
            figures[label] = (stall, write)
            print(f"Parquet, {label} file ({rows} rows): tick stall {stall:.2f} ms, "
                  f"write {write:.1f} ms, {size / rows:.0f} bytes per row")  # fmt: skip
    stall = max(s for s, _ in figures.values())
    passed = stall < MAX_STALL_MS and figures["1 h"][1] < MAX_HOUR_WRITE_MS
    print(f"targets: stall < {MAX_STALL_MS:g} ms ({stall:.2f}), an hour's write < "
          f"{MAX_HOUR_WRITE_MS:g} ms ({figures['1 h'][1]:.1f}): {verdict(passed)}")  # fmt: skip
    return 0 if passed else 1


if __name__ == "__main__":
    raise SystemExit(main())
