"""One recorded run across rotated files: which files continue which, and joining them into one record.

The daemon's recorder rotates its files (every hour, at a size, at a model
change), but the machine ran on: the thermal state at the start of one file
is the state at the end of the one before. Fitted as separate experiments,
each file would start from rest with its own input references, and a model
that is right for the run is wrong for every file after the first. So every
recorded file says which run it belongs to (the recorder's metadata, CSV
``# key: value`` lines, Parquet key-value metadata):

``run_id``
    generated when the daemon starts: a restart starts a new run;
``run_file``
    the file's number in its run, 1 for the first;
``run_previous``
    the name of the run's file before this one;
``run_reason``
    why this file was started: ``start`` (the run's first), ``rotated`` (age or
    size), ``model`` (the active model changed), ``columns`` (the row's keys
    changed), ``clock`` (the clock was set back), ``resumed`` (after a failed
    write), ``reopened`` (the daemon was sent SIGHUP);
``run_gap_s``
    seconds from the previous file's last row to this file's first;

and ``unit.<column>``, each column's unit, and ``machine_id``.

:func:`join_runs` joins the files of one run into one data set when every
link holds: the same ``run_id`` and ``machine_id``, this file's
``run_previous`` is the file before it, ``run_file`` counts on by one, and
the time from the previous file's last sample to this file's first is a
whole number of sample times whose missing samples fill a gap the data
loader would fill (at most ``max_gap_s``, :func:`compd.files.data.load_data`'s
rule); the missing samples are interpolated as the loader interpolates
them. A link that fails splits the run there, with a note saying why.
``contiguous`` mode joins any file to the one before it (in the order given)
on the time rule alone, for files without run metadata (older recordings,
other loggers' files with timestamps); files of different machines are
never joined.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Literal

import numpy as np

from compd.files.columns import (
    MACHINE_ID,
    RUN_FILE,
    RUN_ID,
    RUN_PREVIOUS,
    RUN_REASON,
    UNIT_PREFIX,
)
from compd.files.data import DataSet

#: How the files of several become experiments: each its own, a recorded run's joined, or
#: every file that continues the one before it in time.
Joining = Literal["per-file", "per-run", "contiguous"]
JOININGS: tuple[Joining, ...] = ("per-file", "per-run", "contiguous")
#: A file's first sample may sit this far (a fraction of the sample time) off the grid
#: the previous file's samples continue, as the loader snaps jitter within a file.
GRID_TOLERANCE = 0.1


@dataclass(frozen=True)
class Link:
    """Whether ``data`` continues ``before``: ``missing`` samples between them, or ``why`` not."""

    missing: int
    why: str | None


def join_runs(
    experiments: Sequence[DataSet], *, how: Joining, max_gap_s: float
) -> tuple[list[DataSet], list[str]]:
    """The data sets of ``experiments`` (one per file, alike) joined per ``how``; and what was done.

    The notes say, for each file that could have continued another and did
    not, why; and in one line what the experiments are ("4 files, 1 run of
    24.0 h from mill-a").
    """
    notes: list[str] = []
    if how == "per-file" or len(experiments) < 2:
        return list(experiments), [summary(list(experiments), how)] if len(experiments) > 1 else []
    chains: list[list[DataSet]] = []
    unmarked = 0  # files without run marks that continue the file before them in time
    for data in _in_run_order(experiments):
        target = _predecessor_chain(chains, data, how)
        if target is None:
            if chains and RUN_ID in data.metadata and _file_number(data) == 1:
                notes.append(f"{data.path} starts another run (compd was started again)")
            elif chains and RUN_ID not in data.metadata and RUN_ID not in chains[-1][-1].metadata:
                link = continues(chains[-1][-1], data, how="contiguous", max_gap_s=max_gap_s)
                unmarked += link.why is None
            chains.append([data])
            continue
        link = continues(target[-1], data, how=how, max_gap_s=max_gap_s)
        if link.why is None:
            target.append(data)
        else:
            notes.append(f"{data.path} does not continue {Path(target[-1].path).name}: {link.why}")
            chains.append([data])
    if unmarked:  # an older recording's rotated files, most likely: say so, join only when asked
        notes.append(
            f"{unmarked} file(s) without run marks continue the file before them in time, as "
            "one run's files would; --experiments contiguous joins them into one record"
        )
    joined = [join(chain, max_gap_s=max_gap_s) for chain in chains]
    return joined, [*notes, summary(joined, how)]


def continues(before: DataSet, data: DataSet, *, how: Joining, max_gap_s: float) -> Link:
    """Whether ``data`` continues ``before`` (module docstring's rules for ``how``)."""
    if before.metadata.get(MACHINE_ID) != data.metadata.get(MACHINE_ID):
        return Link(0, f"another machine ({_machine(before)} and {_machine(data)})")
    for key, unit in before.metadata.items():
        other = data.metadata.get(key)
        if key.startswith(UNIT_PREFIX) and other is not None and other != unit:
            column = key.removeprefix(UNIT_PREFIX)
            return Link(0, f"{column} is recorded in {unit} in one and in {other} in the other")
    if how == "per-run":
        if data.metadata.get(RUN_ID) != before.metadata.get(RUN_ID):
            return Link(0, "another run (compd was started again)")
        if (
            data.metadata.get(RUN_PREVIOUS) != Path(before.path).name
            or _file_number(data) != _file_number(before) + 1
        ):
            return Link(
                0, f"the run's file before it, {data.metadata.get(RUN_PREVIOUS)}, is not given"
            )
        if data.metadata.get(RUN_REASON) == "clock":
            return Link(0, "the clock was set back between them")
    if before.start_time is None or data.start_time is None:
        return Link(0, "no timestamps to tell whether one continues the other")
    try:
        gap_s = (data.start_time - before.start_time).total_seconds() - float(before.time_s[-1])
    except TypeError:  # one with a UTC offset, one without
        return Link(0, "one has timestamps with a UTC offset, the other without")
    steps = gap_s / before.sample_time_s
    whole = round(steps)
    if whole < 1:
        return Link(0, f"it starts {_duration(-gap_s)} before the previous one ends")
    if abs(steps - whole) > GRID_TOLERANCE:
        return Link(0, f"its samples are off the previous file's {before.sample_time_s:g} s grid")
    missing = whole - 1
    if missing * before.sample_time_s > max_gap_s:  # the loader's rule for a gap in a file
        return Link(
            missing,
            f"a gap of {_duration(missing * before.sample_time_s)} ({missing} missing samples), "
            f"longer than --max-gap-s {max_gap_s:g} (give a larger one to interpolate it)",
        )
    return Link(missing, None)


def join(chain: Sequence[DataSet], *, max_gap_s: float) -> DataSet:
    """One data set of files that continue each other, the missing samples between them interpolated."""
    first = chain[0]
    if len(chain) == 1:
        return first
    ts_s = first.sample_time_s
    pieces: dict[str, list[np.ndarray]] = {name: [first.column(name)] for name in first.columns}
    notes = [f"{first.path}: {note}" for note in first.notes]
    filled = 0
    for before, data in itertools.pairwise(chain):
        link = continues(before, data, how="contiguous", max_gap_s=max_gap_s)
        for name, parts in pieces.items():
            if link.missing:  # linear, from the last sample before to the first after
                a, b = float(before.column(name)[-1]), float(data.column(name)[0])
                parts.append(a + (b - a) * np.arange(1, link.missing + 1) / (link.missing + 1))
            parts.append(data.column(name))
        filled += link.missing
        notes.extend(f"{data.path}: {note}" for note in data.notes)
    columns = {}
    for name, parts in pieces.items():
        columns[name] = np.concatenate(parts)
        columns[name].flags.writeable = False
    length = len(next(iter(columns.values())))
    time_s = np.arange(length) * ts_s
    time_s.flags.writeable = False
    described = f"joined {len(chain)} files into one record of {_duration(length * ts_s)}"
    if filled:
        described += f"; {filled} missing sample(s) between files interpolated"
    return DataSet(
        path=f"{first.path} .. {Path(chain[-1].path).name}",
        time_s=time_s,
        sample_time_s=ts_s,
        columns=MappingProxyType(columns),
        start_time=first.start_time,
        notes=(described, *notes),
        metadata=first.metadata,
        files=tuple(p for data in chain for p in (data.files or (data.path,))),
    )


def summary(experiments: Sequence[DataSet], how: Joining) -> str:
    """One line: ``4 files, 1 run of 24.0 h from mill-a`` (or what else the experiments are)."""
    files = sum(len(data.files) or 1 for data in experiments)
    machines = sorted({_machine(data) for data in experiments})
    source = (
        f" from {', '.join(machines)}" if any(MACHINE_ID in d.metadata for d in experiments) else ""
    )
    lengths = [len(data) * data.sample_time_s for data in experiments]
    if len({_duration(s) for s in lengths}) == 1:
        hours = _duration(lengths[0]) + (" each" if len(lengths) > 1 else "")
    elif len(lengths) <= 3:
        hours = ", ".join(map(_duration, lengths))
    else:
        hours = f"{_duration(min(lengths))} to {_duration(max(lengths))}"
    runs = {d.metadata.get(RUN_ID) for d in experiments}
    whole_runs = how == "per-run" and None not in runs and len(runs) == len(experiments)
    what = "run" if whole_runs else "experiment"
    counted = f"{len(experiments)} {what}{'s' if len(experiments) != 1 else ''}"
    text = f"{files} files, {counted} of {hours}{source}"
    if how == "per-file":
        text += " (--experiments per-file: each file its own)"
    elif how == "per-run" and not any(RUN_ID in d.metadata for d in experiments):
        text += (
            " (no file says which recorded run it belongs to: each is its own; "
            "--experiments contiguous joins files whose timestamps continue)"
        )
    return text


def _in_run_order(experiments: Sequence[DataSet]) -> list[DataSet]:
    """A run's files by their number, at the place of the run's first file given; others as given."""
    first_seen: dict[str, int] = {}
    keys = []
    for i, data in enumerate(experiments):
        run = data.metadata.get(RUN_ID)
        keys.append((i, 0) if run is None else (first_seen.setdefault(run, i), _file_number(data)))
    order = sorted(range(len(experiments)), key=keys.__getitem__)
    return [experiments[i] for i in order]


def _predecessor_chain(
    chains: list[list[DataSet]], data: DataSet, how: Joining
) -> list[DataSet] | None:
    """The chain ``data`` would continue: its run's file before it (per-run), the last chain (contiguous)."""
    if not chains:
        return None
    if how == "contiguous":
        return chains[-1]
    run = data.metadata.get(RUN_ID)
    if run is None or _file_number(data) <= 1:
        return None
    for chain in reversed(chains):  # a run's file before it is the last of its run's chain
        if chain[-1].metadata.get(RUN_ID) == run:
            return chain
    return None


def _file_number(data: DataSet) -> int:
    try:
        return int(data.metadata.get(RUN_FILE, "0"))
    except ValueError:
        return 0


def _machine(data: DataSet) -> str:
    return data.metadata.get(MACHINE_ID, "an unnamed machine")


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return f"{seconds} s"
    if abs(seconds) >= 3600:
        return f"{seconds / 3600:.1f} h"
    if abs(seconds) >= 60:
        return f"{seconds / 60:.1f} min"
    return f"{seconds:g} s"


__all__ = ["JOININGS", "Joining", "join", "join_runs", "summary"]
