"""Measured displacements taken as changes from the record's start when they were logged otherwise.

The rule and why: :mod:`compd.model.outputstart`. Applied where a command
pairs a model with measured columns (``fit``'s output, ``evaluate``'s
outputs and displacement columns), per experiment, before anything is
fitted or judged; each zeroed column leaves a note in the data's notes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from types import MappingProxyType

from compd.files.data import DataSet
from compd.model.outputstart import unzeroed_start


def zero_displacements(data: DataSet, columns: Iterable[str]) -> tuple[DataSet, tuple[str, ...]]:
    """``data`` with each of ``columns`` that did not start at 0 as its change from its first value.

    Returns the data (the same object when nothing changed) and the notes
    added (one per column zeroed), which the returned
    data's notes end with.
    """
    changed = {}
    notes = []
    for name in dict.fromkeys(columns):
        if not data.has(name):
            continue
        values = data.column(name)
        start = unzeroed_start(values)
        if start is None:
            continue
        zeroed = values - start
        zeroed.flags.writeable = False
        changed[name] = zeroed
        notes.append(
            f"{name} starts at {start:.4g} um, not at 0 (it moves {float(values.max() - values.min()):.3g} "
            "um over the record): taken as its change from that first value, as the inputs are "
            "and as every model predicts it (a probe not zeroed at the start, or a file split off "
            "a longer log). Zero the column in the file to silence this note"
        )
    if not changed:
        return data, ()
    columns_now = MappingProxyType({**data.columns, **changed})
    return dataclasses.replace(data, columns=columns_now, notes=(*data.notes, *notes)), tuple(notes)
