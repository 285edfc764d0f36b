"""A part of one continuous record, chosen by time: what ``--from`` and ``--until`` select.

A model fitted on the first 32 h of a log and judged on the rest must be
judged as it would have run on the machine: from the start of the log, with
every input's reference (its first value) and the model state of the whole
log. Splitting the file instead silently moves both to the split. So a
:class:`Span` never cuts the start of a record before a model runs over it:
the model runs from the file's first sample, only the samples in
``[from, until)`` are fitted or scored, and nothing after ``until`` is read
(a causal model's output before ``until`` cannot depend on it, so a fit
``--until`` a cut is the same whatever the file holds after the cut).
The measured displacement is used as logged: ``--from`` does not re-zero it.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from compd.errors import DataFileError
from compd.files.data import DataSet
from compd.files.modelfile import ModelFile
from compd.toolkit.evaluate import Evaluation, InitialState, evaluate

_CLOCK = re.compile(r"^\s*(\d+):([0-5]?\d)(?::([0-5]?\d(?:\.\d*)?))?\s*$")


def parse_time_s(text: str) -> float:
    """Seconds from a record's start: ``7200``, ``1800.5``, ``32:06`` (h:m) or ``32:06:30`` (h:m:s).

    Raises ``ValueError`` with the accepted forms when ``text`` is none of them.
    """
    clock = _CLOCK.match(text)
    if clock is not None:
        hours, minutes, seconds = clock.groups()
        return int(hours) * 3600.0 + int(minutes) * 60.0 + float(seconds or 0.0)
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 <= value < float("inf"):
        raise ValueError(
            f"{text!r} is not a time from the record's start: give seconds >= 0 (e.g. 115560) "
            "or hours:minutes[:seconds] (e.g. 32:06)"
        )
    return value


def clock(seconds: float) -> str:
    """``h:mm`` (or ``h:mm:ss`` when not on a whole minute) from the record's start."""
    whole = round(seconds)
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}" + (f":{secs:02d}" if secs else "")


@dataclass(frozen=True)
class Span:
    """Samples ``start .. stop - 1`` of a record: ``[from_s, until_s)`` on its sample grid.

    ``from_s`` / ``until_s`` are as given (``None``: the record's start / end),
    in seconds from the record's first sample; each selects the sample nearest
    to it (``until_s``'s is the first one left out).
    """

    path: str
    from_s: float | None
    until_s: float | None
    start: int
    stop: int
    sample_time_s: float

    @property
    def whole(self) -> bool:
        """Neither option given: the whole record, exactly as without them."""
        return self.from_s is None and self.until_s is None

    @property
    def first_s(self) -> float:
        return self.start * self.sample_time_s

    @property
    def last_s(self) -> float:
        return (self.stop - 1) * self.sample_time_s

    def describe(self, verb: str) -> str:
        """E.g. ``judged on 32.10 h .. 46.00 h (3336 samples) of FILE, model run from the ...``."""
        return (
            f"{verb} on {self.first_s / 3600:.2f} h .. {self.last_s / 3600:.2f} h "
            f"({self.stop - self.start} samples) of {self.path}, model run from the file's start"
        )

    def json(self) -> dict[str, float | None]:
        """``from_s`` and ``until_s`` as given (null when not), for JSON outputs."""
        return {"from_s": self.from_s, "until_s": self.until_s}


def resolve_span(
    data: DataSet, from_s: float | None, until_s: float | None, *, min_samples: int = 2
) -> Span:
    """The samples of ``data`` in ``[from_s, until_s)``, or an error naming the option and the span.

    ``min_samples``: fewest samples the caller can work with (a fit, a
    cross-validation); fewer is an error.
    """
    step = data.sample_time_s
    end_s = float(data.time_s[-1]) + step  # the last sample holds until then
    record = (
        f"the record spans 0 .. {clock(end_s)} ({end_s / 3600:.2f} h, {len(data)} samples of "
        f"{step:g} s)"
    )
    if from_s is not None and until_s is not None and from_s >= until_s:
        raise DataFileError(
            data.path,
            f"--from {clock(from_s)} is not before --until {clock(until_s)}",
            where="--from",
            fix=f"Give --from before --until; {record}",
        )
    for option, value in (("--from", from_s), ("--until", until_s)):
        if value is not None and not 0.0 <= value <= end_s:
            raise DataFileError(
                data.path,
                f"{option} {clock(value)} ({value:g} s) is outside the record",
                where=option,
                fix=f"Give a time within it; {record}",
            )
    # Half a sample of slack: a time given as a sample's time selects that sample.
    start = 0 if from_s is None else int(np.searchsorted(data.time_s, from_s - 0.5 * step))
    stop = len(data) if until_s is None else int(np.searchsorted(data.time_s, until_s - 0.5 * step))
    if stop - start < min_samples and from_s is None and until_s is None:
        raise DataFileError(
            data.path,
            f"the record holds {len(data)} samples, fewer than the {min_samples} needed",
            fix=longer_record_fix(min_samples, step),
        )
    if stop - start < min_samples:
        where = "--from" if until_s is None else "--until"
        raise DataFileError(
            data.path,
            f"--from/--until select {max(stop - start, 0)} samples, fewer than the "
            f"{min_samples} needed",
            where=where,
            fix=f"Widen the window; {record}",
        )
    return Span(data.path, from_s, until_s, start, stop, step)


def longer_record_fix(min_samples: int, sample_time_s: float) -> str:
    """What to give instead of a record too short to work on: the samples, and the hours they take."""
    hours = min_samples * sample_time_s / 3600
    return (
        f"Give a record of at least {min_samples} samples ({hours:.3g} h at {sample_time_s:g} s): "
        "a longer one, or one logged at a shorter sample time"
    )


def until_stop(data: DataSet, span: Span) -> DataSet:
    """``data`` from its first sample up to the span's end: what a model runs over."""
    return data if span.stop == len(data) else _rows(data, 0, span.stop)


def evaluate_span(
    model_file: ModelFile, data: DataSet, span: Span, *, init: InitialState = "steady"
) -> Evaluation:
    """``model_file`` run over ``data`` from its first sample; the part ``span`` selects."""
    later = span.start > 0  # the samples before it are run through, never judged: as logged
    return scored_part(
        evaluate(model_file, until_stop(data, span), init=init, as_logged=later), span
    )


def span_data(data: DataSet, span: Span) -> DataSet:
    """The span's samples of ``data`` (times from the record's start): what was fitted or judged."""
    return data if (span.start, span.stop) == (0, len(data)) else _rows(data, span.start, span.stop)


def scored_part(evaluation: Evaluation, span: Span) -> Evaluation:
    """The span's samples of a run over :func:`until_stop` data, remembering the whole run.

    Every sample keeps its time from the record's start; the measured
    columns are as logged (not re-zeroed). ``whole`` lets a consumer that
    filters signals (``diagnose``) start its filters at the record's start too.
    """
    if span.whole:
        return evaluation
    if span.start == 0:
        return dataclasses.replace(evaluation, span=span)
    result = evaluation.result
    cut = slice(span.start, None)
    return dataclasses.replace(
        evaluation,
        data=span_data(evaluation.data, span),
        result=dataclasses.replace(
            result,
            outputs=result.outputs[cut],
            contributions=result.contributions[cut],
            residuals=None if result.residuals is None else result.residuals[cut],
        ),
        span=span,
        whole=evaluation,
    )


def _rows(data: DataSet, start: int, stop: int) -> DataSet:
    """Samples ``start .. stop - 1`` of ``data``: read-only views, times unchanged.

    So ``time_s[0]`` is the span's start, not 0: every time shown stays a time
    of the record a user can find in the file.
    """
    columns = {name: values[start:stop] for name, values in data.columns.items()}
    return dataclasses.replace(
        data, time_s=data.time_s[start:stop], columns=MappingProxyType(columns)
    )
