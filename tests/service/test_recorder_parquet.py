"""Parquet recorder: row groups, footer metadata, rotation, and files that survive a SIGKILL."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from numpy.testing import assert_allclose

from compd.files.data import load_data
from compd.files.experiments import load_experiments
from compd.service import build
from compd.service.config.docs import RecorderDoc
from compd.service.recording.parquet import RETRY_MAX_S, ParquetRecorder
from compd.service.recording.recorder import Recorder

T0_S = 1_795_428_900.0  # 2026-11-23T10:15:00Z
BIG = 1 << 30
META = {"machine_id": "lathe-3", "compd_version": "0.1.0", "config": "/etc/compd/compd.yaml"}


def make(directory: Path, **options: float) -> ParquetRecorder:
    limits = {"max_file_bytes": BIG, "max_file_age_s": 1e6, "max_total_bytes": 4 * BIG}
    return ParquetRecorder(directory, metadata=META, **(limits | options))  # type: ignore[arg-type]


def row(k: int) -> dict[str, float | int | str]:
    return {"T_spindle_degC": 20.0 + 0.01 * k, "status": k % 3, "model.disp_z_um": -0.5 * k}


def test_a_file_holds_every_row_and_names_the_machine_in_its_footer(tmp_path: Path) -> None:
    """Rows written every flush_every_rows and at close; the footer names machine, compd, model, config."""
    with make(tmp_path, flush_every_rows=10) as rec:
        rec.set_model("twin-z", "ab" * 32)
        for k in range(35):
            rec.record(row(k), at_s=T0_S + k)
    (path,) = tmp_path.glob("compd-*.parquet")
    assert path.name == f"compd-{META['machine_id']}-20261123T101500Z.parquet"
    parquet = pq.ParquetFile(path)
    assert parquet.metadata.num_row_groups == 1  # up to an hour's rows in one
    assert parquet.metadata.num_rows == 35
    metadata = {k.decode(): v.decode() for k, v in parquet.schema_arrow.metadata.items()}
    assert metadata.items() >= (META | {"model": "twin-z", "model_sha256": "ab" * 32}).items()
    data = load_data(path)
    assert dict(data.metadata) == metadata
    assert data.sample_time_s == 1.0 and data.start_time is not None
    assert data.start_time.timestamp() == T0_S
    assert_allclose(data.column("model.disp_z_um"), [-0.5 * k for k in range(35)])
    assert_allclose(data.column("status"), [k % 3 for k in range(35)])


def test_files_rotate_by_age_and_on_a_new_model_and_load_as_experiments(tmp_path: Path) -> None:
    """Age and a model change start new files: one run, one experiment per file when asked."""
    with make(tmp_path, flush_every_rows=7, max_file_age_s=50) as rec:
        rec.set_model("a", "1" * 64)
        for k in range(120):
            if k == 100:
                rec.set_model("b", "2" * 64)
            rec.record(row(k), at_s=T0_S + k)
    assert [len(e) for e in load_experiments([tmp_path])] == [120]
    experiments = load_experiments([tmp_path], joining="per-file")
    assert [len(e) for e in experiments] == [50, 50, 20]
    assert [e.metadata["model"] for e in experiments] == ["a", "a", "b"]


def test_the_disk_budget_counts_both_formats(tmp_path: Path) -> None:
    """Old recordings are deleted to stay under max_total_bytes, whichever format wrote them."""
    old = tmp_path / "compd-20200101T000000Z.csv"
    old.write_bytes(b"x" * 5000)
    with make(tmp_path, max_file_bytes=2048, max_total_bytes=4096, flush_every_rows=5) as rec:
        for k in range(10):
            rec.record(row(k), at_s=T0_S + k)
    assert not old.exists()
    assert len(list(tmp_path.glob("compd-*.parquet"))) == 1


def test_the_config_builds_the_parquet_recorder(tmp_path: Path) -> None:
    """recorder.format: parquet: the builder makes one flushing every 60 rows unless told; csv is the default."""
    doc = RecorderDoc.model_validate({"format": "parquet"})
    recorder = build.recorder(doc, tmp_path, {"machine_id": "m1"})
    assert isinstance(recorder, ParquetRecorder) and recorder.flush_every_rows == 60
    assert recorder.metadata == {"machine_id": "m1"}
    assert isinstance(build.recorder(RecorderDoc(), tmp_path), Recorder)
    with pytest.raises(ValueError, match="format"):
        RecorderDoc.model_validate({"format": "xlsx"})


WRITER = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    from compd.service.recording.parquet import ParquetRecorder

    rec = ParquetRecorder(
        Path(sys.argv[1]), max_file_bytes=1 << 30, max_file_age_s=300,
        max_total_bytes=1 << 32, flush_every_rows=20, metadata={"machine_id": "kill-me"},
    )
    k = 0
    while True:  # until SIGKILL: 1 s rows, a file every 300 rows
        rec.record({"T_degC": 20.0 + 0.001 * k, "x_um": float(k)}, at_s=1.8e9 + k)
        k += 1
    """
)


def test_a_sigkilled_recorder_leaves_files_readable_up_to_their_last_flush(
    tmp_path: Path,
) -> None:
    """SIGKILL mid-run: every file on disk loads, holds whole row groups, and names its machine."""
    records = tmp_path / "records"
    child = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(records)], cwd=Path(__file__).parents[2]
    )
    try:
        deadline = time.monotonic() + 120  # a safety net, not an assertion on speed
        while len(list(records.glob("compd-*.parquet"))) < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
    assert child.returncode == -signal.SIGKILL
    files = sorted(records.glob("compd-*.parquet"))
    assert len(files) >= 3, "the writer did not get far enough"
    experiments = load_experiments([records], joining="per-file")
    sizes = [len(e) for e in experiments]
    assert sizes[:-1] == [300] * (len(sizes) - 1)  # closed files: whole
    assert sizes[-1] % 20 == 0 and sizes[-1] >= 20  # the open one: up to its last row group
    assert all(e.metadata["machine_id"] == "kill-me" for e in experiments)
    first = experiments[0].column("x_um")
    assert_allclose(first, range(300))  # no row lost or repeated before the crash


#: Records 3,000 rows at 1 s into a tmpfs of its own; fills the disk at row 300, frees it at row
#: 2,000; prints what it saw as JSON (the tmpfs goes with the mount namespace).
FULL_DISK = textwrap.dedent(
    """
    import json, os, sys
    from pathlib import Path
    import pyarrow.parquet as pq
    from compd.errors import RecorderError
    from compd.service.recording.parquet import ParquetRecorder

    disk, bound = Path(sys.argv[1]), int(sys.argv[2])
    options = {"max_unwritten_rows": bound} if bound else {}
    rec = ParquetRecorder(
        disk / "rec", max_file_bytes=1 << 30, max_file_age_s=600, max_total_bytes=1 << 32,
        flush_every_rows=60, **options,
    )
    episodes, lost, failing, filler = 0, 0, False, disk / "filler"
    for k in range(3000):
        if k == 300:  # the disk fills up: 4 KiB pages until there is none
            fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
            try:
                while True:
                    os.write(fd, bytes(4096))
            except OSError:
                os.close(fd)
        if k == 2000:
            filler.unlink()
        try:
            rec.record({"k": float(k), "x_um": 0.5 * k}, at_s=1.8e9 + k)
        except RecorderError:
            episodes += not failing
            failing = True
        else:
            if failing:
                lost += getattr(rec, "take_lost_rows", lambda: 0)()
            failing = False
    rec.close()
    ks = [k for f in sorted((disk / "rec").glob("compd-*.parquet"))
          for k in pq.read_table(f).column("k").to_pylist()]
    print(json.dumps({"episodes": episodes, "lost": lost, "ks": ks}))
    """
)


def on_a_small_tmpfs(tmp_path: Path, script: str, *args: object) -> dict[str, Any]:
    """Run ``script`` with a 1 MiB tmpfs of its own (a mount namespace: unshare -rm); its JSON output."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["unshare", "-rm", "true"], capture_output=True).returncode != 0:
        pytest.skip("no mount namespaces here (unshare -rm): a real full disk needs one")
    command = 'mount -t tmpfs -o size=1m tmpfs "$1" && shift && exec "$@"'
    done = subprocess.run(
        ["unshare", "-rm", "sh", "-c", command, "sh", str(disk), sys.executable, "-c", script,
         str(disk), *map(str, args)],
        capture_output=True, text=True, timeout=300, cwd=Path(__file__).parents[2],
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    result: dict[str, Any] = json.loads(done.stdout.splitlines()[-1])
    return result


def test_a_full_disk_is_one_fault_and_no_row_is_lost_within_the_bound(tmp_path: Path) -> None:
    """1,700 s of a full tmpfs (rotation due meanwhile): one failure episode, then every row on disk, in order."""
    result = on_a_small_tmpfs(tmp_path, FULL_DISK, 0)
    assert result["episodes"] == 1
    assert result["lost"] == 0
    assert result["ks"] == [float(k) for k in range(3000)]


def test_rows_beyond_the_bound_are_lost_and_counted_once_it_recovers(tmp_path: Path) -> None:
    """With 500 rows kept at most, the outage's other rows are lost, and the count says how many exactly."""
    result = on_a_small_tmpfs(tmp_path, FULL_DISK, 500)
    assert result["episodes"] == 1
    ks = result["ks"]
    assert ks == sorted(set(ks)) and len(ks) + result["lost"] == 3000
    # 1,700 s of outage less the 500 rows kept; the retry may come up to RETRY_MAX_S late.
    assert 1700 - 500 - 60 <= result["lost"] <= 1700 + RETRY_MAX_S - 500


SYNCED = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    from compd.service.recording.parquet import ParquetRecorder

    rec = ParquetRecorder(Path(sys.argv[1]), max_file_bytes=1 << 30, max_file_age_s=600,
                          max_total_bytes=1 << 32, flush_every_rows=10)
    for k in range(10):
        rec.record({"x_um": float(k)}, at_s=1.8e9 + k)
    rec.close()
    """
)


def test_each_write_is_synced_before_and_after_its_rename(tmp_path: Path) -> None:
    """strace: fsync of the .tmp, its rename over the file, fsync of the folder (a power cut keeps a whole file)."""
    if shutil.which("strace") is None:
        pytest.skip("strace is not installed")
    records, trace = tmp_path / "records", tmp_path / "trace"
    done = subprocess.run(
        ["strace", "-f", "-y", "-o", str(trace), "-e", "trace=fsync,fdatasync,rename,renameat,renameat2",
         sys.executable, "-c", SYNCED, str(records)],
        capture_output=True, text=True, timeout=120, cwd=Path(__file__).parents[2],
    )  # fmt: skip
    if done.returncode != 0 and "ptrace" in done.stderr:
        pytest.skip(f"strace cannot trace here: {done.stderr[-200:]}")
    assert done.returncode == 0, done.stderr[-2000:]
    (path,) = records.glob("compd-*.parquet")
    calls = [
        line.split(None, 1)[1] for line in trace.read_text().splitlines() if str(records) in line
    ]
    steps = []
    for call in calls:
        if call.startswith(("fsync", "fdatasync")) and f"{path}.tmp>" in call:
            steps.append("sync tmp")
        elif call.startswith("rename") and f"{path}.tmp" in call:
            steps.append("rename")
        elif call.startswith(("fsync", "fdatasync")) and f"<{records}>" in call:
            steps.append("sync folder")
    assert steps == ["sync tmp", "rename", "sync folder"], calls
