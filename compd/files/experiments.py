"""Several data files as experiments: a folder or a list of files, each recorded run one record.

Recordings of a fleet come as folders of files (the recorder rotates them),
several days of one machine, or several machines of one type. Each file is
loaded on its own (:func:`~compd.files.data.load_data`, so every check and
repair names its file); then the files of one recorded run, which say so in
their metadata, are joined into one experiment (:mod:`compd.files.runs`):
the machine's thermal state carried over from one file to the next. Separate
runs, other machines and files that say nothing (older recordings, other
loggers' files) are separate experiments, since nothing says the state
carried over; ``joining`` changes that both ways (``per-file``: every file
its own, as before run metadata; ``contiguous``: any file whose timestamps
continue the one before it). The commands run the model from its initial
state at each experiment's start, the fit takes no lag across experiments
(:mod:`compd.model.experiments`), and cross-validation leaves one out.

The files must be alike: the same columns (a file without a column another
has is refused, naming both) and the same sample time. In a folder, a file
of fewer than two rows (a recorder stopped just after it rotated) is left
out with a note: it holds no time step, so no experiment.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np

from compd.errors import DataFileError
from compd.files.data import PARQUET_SUFFIXES, DataSet, load_data
from compd.files.runs import Joining, join_runs

#: File names read from a folder, sorted by name (the recorder's names sort by time).
FOLDER_SUFFIXES = (".csv", *PARQUET_SUFFIXES)
#: Relative difference of sample times that still counts as the same.
SAMPLE_TIME_TOLERANCE = 1e-6


def data_paths(
    paths: Sequence[str | os.PathLike[str]], notes: list[str] | None = None
) -> list[Path]:
    """The files ``paths`` name: a file as given, a folder as its CSV and Parquet files sorted by name.

    A folder's files of fewer than two rows are left out, each with a line in ``notes``.
    """
    found: list[Path] = []
    for given in map(Path, paths):
        if not given.is_dir():
            found.append(given)  # a missing file is named by load_data
            continue
        inside = []
        for path in sorted(given.iterdir()):
            if not path.is_file() or path.suffix.lower() not in FOLDER_SUFFIXES:
                continue
            rows = _row_count(path)
            if rows is not None and rows < 2:
                if notes is not None:
                    notes.append(f"left out {path}: {rows} row(s), too short to be an experiment")
                continue
            inside.append(path)
        if not inside:
            raise DataFileError(
                str(given),
                "the folder holds no data file",
                fix=f"Give a folder with {', '.join(FOLDER_SUFFIXES)} files, or the files themselves",
            )
        found.extend(inside)
    seen: set[Path] = set()
    for path in found:
        if path.resolve() in seen:
            raise DataFileError(
                str(path), "is given twice", fix="Name each file (or its folder) once"
            )
        seen.add(path.resolve())
    return found


def load_experiments(
    paths: Sequence[str | os.PathLike[str]],
    *,
    max_gap_s: float = 60.0,
    resample: bool = False,
    joining: Joining = "per-run",
) -> list[DataSet]:
    """The files of ``paths`` (:func:`data_paths`) as experiments, joined per ``joining``.

    Refused unless alike. The first experiment's notes say what was joined
    and what not (:func:`compd.files.runs.join_runs`).
    """
    notes: list[str] = []
    experiments = [
        load_data(path, max_gap_s=max_gap_s, resample=resample) for path in data_paths(paths, notes)
    ]
    check_alike(experiments)
    experiments, joined = join_runs(experiments, how=joining, max_gap_s=max_gap_s)
    notes.extend(joined)
    if notes:  # said once, with the first experiment's notes (the commands print those)
        first = experiments[0]
        experiments[0] = dataclasses.replace(first, notes=(*first.notes, *notes))
    return experiments


def _row_count(path: Path) -> int | None:
    """Data rows in a file, cheaply (Parquet's footer; a CSV's lines); None if it cannot tell."""
    try:
        if path.suffix.lower() in PARQUET_SUFFIXES:
            import pyarrow.parquet as pq

            return int(pq.ParquetFile(path).metadata.num_rows)
        with open(path, "rb") as handle:
            lines = 0  # the header and up to two rows, after the metadata comments
            for line in handle:
                lines += not (lines == 0 and line.startswith(b"#"))
                if lines == 3:
                    return None  # two rows or more: load_data counts them
    except Exception:  # pyarrow's errors too: load_data reads the file again and names them
        return None
    return max(lines - 1, 0)


def check_alike(experiments: Sequence[DataSet]) -> None:
    """Refuse experiments with different columns or sample times, naming the file that differs."""
    first = experiments[0]
    for data in experiments[1:]:
        for a, b in ((first, data), (data, first)):
            missing = [name for name in a.columns if name not in b.columns]
            if missing:
                raise DataFileError(
                    b.path,
                    f"there is no column {missing[0]!r}, which {a.path} has"
                    + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""),
                    fix="Give files that record the same signals, or leave this one out",
                )
        if not np.isclose(
            data.sample_time_s, first.sample_time_s, rtol=SAMPLE_TIME_TOLERANCE, atol=0.0
        ):
            raise DataFileError(
                data.path,
                f"the sample time is {data.sample_time_s:g} s, {first.path}'s "
                f"{first.sample_time_s:g} s",
                fix="Give files recorded at one sample time (a model runs at one)",
            )


@dataclass(frozen=True, eq=False)
class Stacked:
    """Experiments end to end in one :class:`DataSet`, and where each starts (its first sample).

    For fitting only: the stacked data set's columns run through every file, so
    anything that filters them must restart at ``starts``.
    """

    data: DataSet
    starts: tuple[int, ...]
    experiments: tuple[DataSet, ...]


def single(data: DataSet) -> Stacked:
    """One record as a stack of one experiment (the data set itself, unchanged)."""
    return Stacked(data, (0,), (data,))


def as_stacked(data: DataSet | Stacked | Sequence[DataSet]) -> Stacked:
    """``data`` as experiments: a stack as it is, one record as a stack of one, several end to end."""
    if isinstance(data, Stacked):
        return data
    if isinstance(data, DataSet):
        return single(data)
    return stack(data) if len(data) > 1 else single(data[0])


def stack(experiments: Sequence[DataSet]) -> Stacked:
    """One data set of ``experiments`` end to end (columns as each file's: references are the caller's)."""
    check_alike(experiments)
    first = experiments[0]
    lengths = [len(data) for data in experiments]
    starts = tuple(int(s) for s in np.cumsum([0, *lengths[:-1]]))
    columns = {}
    for name in first.columns:
        joined = np.concatenate([data.column(name) for data in experiments])
        joined.flags.writeable = False
        columns[name] = joined
    time_s = np.arange(sum(lengths)) * first.sample_time_s
    time_s.flags.writeable = False
    notes = tuple(f"{data.path}: {note}" for data in experiments for note in data.notes)
    data = DataSet(
        path=", ".join(data.path for data in experiments),
        time_s=time_s,
        sample_time_s=first.sample_time_s,
        columns=MappingProxyType(columns),
        start_time=first.start_time,
        notes=notes,
        metadata=first.metadata,
    )
    return Stacked(data, starts, tuple(experiments))
