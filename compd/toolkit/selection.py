"""Columns chosen by name, glob or ``all``: what ``--inputs`` and ``--candidates`` take.

A machine log carries 16 temperatures; typing them out invites a missed one.
``T*`` or ``all`` says what the user means. ``all`` is every logged signal
that is not a displacement (the output and the other measured channels,
named ``disp_*`` or ``*_um`` by compd's data contract) and not otherwise
taken (the caller's ``exclude``: the output, a position column). A pattern
never matches an excluded column either; a pattern that matches nothing is
an error, because a silently empty selection fits a different model.
"""

from __future__ import annotations

from collections.abc import Sequence
from fnmatch import fnmatchcase

from compd.errors import DataFileError
from compd.files.columns import is_recorded_column
from compd.files.data import DataSet

#: Column names of measured displacements (case-insensitive): never an input under ``all``.
DISPLACEMENT_PATTERNS = ("disp_*", "*_um")
_GLOB_CHARACTERS = frozenset("*?[")


def is_displacement(name: str) -> bool:
    return any(fnmatchcase(name.lower(), p) for p in DISPLACEMENT_PATTERNS)


def select_columns(
    data: DataSet, text: str, *, option: str, exclude: Sequence[str] = ()
) -> list[str]:
    """The columns ``text`` names: comma-separated names, globs (``T*``, ``spindle_*``) or ``all``.

    Plain names are kept as given, repeats included, so the caller's own
    checks (unknown column, named twice, the output as an input) still
    speak; a glob or ``all`` adds the columns it matches that are not
    ``exclude``\\ d and not already chosen, in the file's column order; ``all``
    means the signals, never a displacement nor what compd's recorder adds
    beside them (``health.*``, ``read.*``, ``model.*``, ``status``, ...).
    """
    chosen: list[str] = []
    eligible = [name for name in data.columns if name not in exclude]
    for item in (part.strip() for part in text.split(",")):
        if not item:
            continue
        if item.lower() == "all":  # the signals: not displacements, nor the recorder's own columns
            matches = [
                name
                for name in eligible
                if not is_displacement(name) and not is_recorded_column(name)
            ]
        elif _GLOB_CHARACTERS & set(item):
            matches = [name for name in eligible if fnmatchcase(name, item)]
        else:
            chosen.append(item)
            continue
        if not matches:
            raise DataFileError(
                data.path,
                f"{item!r} matches no column"
                + (f" (excluded here: {', '.join(exclude)})" if exclude else ""),
                where=option,
                fix=f"Use names or globs (case-sensitive) of the file's columns: "
                f"{', '.join(data.columns)}",
            )
        chosen.extend(name for name in matches if name not in chosen)
    return chosen
