"""Probe files: sparse TCP measurements (a touch probe at tool changes) read for ``compd update``.

A CSV with ``time_s`` (seconds from the data file's first sample, as compd
counts time) and one column per probed output, named like the model output
(``disp_z_um``); an empty or NaN cell means that axis was not probed at that
instant. Every problem names the file, the line (the header is line 1), the
column and the fix, as :mod:`compd.files.data` does. Probes need not fall on the
data's sample grid: each gain's simulated contribution is interpolated
linearly at the probe instants.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from compd.errors import DataFileError, ModelFileError
from compd.files.modelfile import ModelFile
from compd.toolkit.gainsets import Decomposition


@dataclass(frozen=True, eq=False)
class Probes:
    """Sparse measurements: ``values[output]`` (um) at ``time_s``, NaN where not probed."""

    path: str
    time_s: np.ndarray
    values: dict[str, np.ndarray]
    lines: np.ndarray  # the file line of each probe (the header is line 1)


def load_probes(path: str | Path) -> Probes:
    """Read a probe CSV; every problem names the file, the line and the column."""
    text = str(path)
    try:
        frame = pd.read_csv(text, dtype=str, keep_default_na=False, skip_blank_lines=True)
    except (OSError, UnicodeDecodeError, pd.errors.ParserError) as exc:
        raise DataFileError(text, f"cannot read the probe file ({exc})") from exc
    except pd.errors.EmptyDataError:
        raise DataFileError(
            text, "the file is empty", fix="Write a header: time_s,disp_z_um"
        ) from None
    frame.columns = [str(c).strip() for c in frame.columns]
    if "time_s" not in frame.columns:
        raise DataFileError(
            text,
            f"there is no time_s column (header: {', '.join(frame.columns)})",
            where="line 1",
            fix="Name the probe instants' column time_s (seconds from the data file's first sample)",
        )
    axes = [c for c in frame.columns if c != "time_s"]
    if not axes or frame.empty:
        raise DataFileError(
            text,
            "no probe measurements",
            where="line 1",
            fix="Add one column per probed output (e.g. disp_z_um) and one row per probe instant",
        )
    lines = np.arange(len(frame)) + 2
    columns = {name: _numbers(text, frame[name], name, lines) for name in ["time_s", *axes]}
    time_s = columns.pop("time_s")
    bad = ~np.isfinite(time_s)
    if bad.any():
        raise DataFileError(
            text,
            "the probe time is empty or not a number",
            where=f"line {lines[np.argmax(bad)]}, column time_s",
            fix="Give every probe its time in seconds",
        )
    steps = np.diff(time_s)
    if (steps <= 0).any():
        i = int(np.argmax(steps <= 0)) + 1
        raise DataFileError(
            text,
            f"time {time_s[i]:g} s does not come after {time_s[i - 1]:g} s",
            where=f"line {lines[i]}, column time_s",
            fix="Sort the probes by time and merge repeated instants into one row",
        )
    return Probes(text, time_s, columns, lines)


def _numbers(path: str, cells: pd.Series, name: str, lines: np.ndarray) -> np.ndarray:
    stripped = cells.str.strip()
    missing = stripped.isin(["", "NaN", "nan", "NA"])
    values: np.ndarray = np.asarray(
        pd.to_numeric(stripped.where(~missing), errors="coerce"), dtype=float
    )
    bad = (np.isnan(values) & ~missing.to_numpy()) | np.isinf(values)
    if bad.any():
        i = int(np.argmax(bad))
        raise DataFileError(
            path,
            f"{cells.iloc[i]!r} is not a number",
            where=f"line {lines[i]}, column {name}",
            fix="Give the displacement in um, or leave the cell empty when that axis was not probed",
        )
    return values


def probed_outputs(model_file: ModelFile, probes: Probes, output: str | None) -> list[str]:
    """The model outputs to update: ``output``, or every output the probe file has a column for."""
    names = [o.name for o in model_file.model.outputs]
    if output is not None:
        if output not in names:
            raise ModelFileError(
                model_file.path,
                f"the model has no output {output!r}",
                where="--output",
                fix=f"Use one of {', '.join(names)}",
            )
        if output not in probes.values:
            raise DataFileError(
                probes.path,
                f"there is no column {output!r}",
                where="line 1",
                fix=f"Name the probed displacement column {output}",
            )
        return [output]
    unknown = [c for c in probes.values if c not in names]
    if unknown:
        raise DataFileError(
            probes.path,
            f"column(s) {', '.join(unknown)} name no output of the model",
            where="line 1",
            fix=f"Name each probe column after a model output ({', '.join(names)}), or pass --output",
        )
    return list(probes.values)


@dataclass(frozen=True, eq=False)
class ProbeRows:
    """The probed values as optimiser rows: one per (instant, output) with a measurement."""

    time_s: np.ndarray
    output: tuple[str, ...]
    measured_um: np.ndarray
    contributions_um: np.ndarray  # (P, G)
    fixed_um: np.ndarray  # (P,)


def probe_rows(decomposition: Decomposition, probes: Probes, outputs: list[str]) -> ProbeRows:
    """Interpolate each gain's contribution linearly at the probe instants (they need not be on the grid)."""
    data = decomposition.data
    end_s = float(data.time_s[-1])
    outside = (probes.time_s < 0.0) | (probes.time_s > end_s)
    if outside.any():
        i = int(np.argmax(outside))
        raise DataFileError(
            probes.path,
            f"probe time {probes.time_s[i]:g} s is outside the data file's 0..{end_s:g} s "
            f"({data.path})",
            where=f"line {probes.lines[i]}, column time_s",
            fix="Probe times count seconds from the data file's first sample; remove the probe "
            "or use the data of the run it was taken in",
        )
    times, names, measured, rows, fixed = [], [], [], [], []
    for output in outputs:
        values = probes.values[output]
        taken = np.isfinite(values)
        t = probes.time_s[taken]
        c = decomposition.contributions[output]
        times.append(t)
        names += [output] * int(taken.sum())
        measured.append(values[taken])
        rows.append(
            np.column_stack([np.interp(t, data.time_s, c[:, j]) for j in range(c.shape[1])])
        )
        fixed.append(np.interp(t, data.time_s, decomposition.fixed[output]))
    return ProbeRows(
        np.concatenate(times),
        tuple(names),
        np.concatenate(measured),
        np.vstack(rows),
        np.concatenate(fixed),
    )
