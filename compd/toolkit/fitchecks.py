"""The checks ``compd fit`` makes of its options before fitting, each refusal naming file, option and fix.

Kept apart from :mod:`compd.toolkit.fit` so the fit itself reads as the steps
it takes; every check here only reads the data set and raises
:class:`~compd.errors.DataFileError`.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from compd.errors import DataFileError
from compd.files.columns import UNIT_PREFIX
from compd.files.data import DataSet
from compd.model.orderfit import MAX_ORDER
from compd.toolkit.evaluate import check_step
from compd.toolkit.fitmodel import column_unit
from compd.toolkit.methods import FIT_METHODS


def check_arguments(
    data: DataSet, output: str, inputs: Sequence[str], order: int | str, method: str
) -> None:
    """Refuse missing, repeated or constant inputs, an unknown column, order or method."""
    if not inputs:
        raise DataFileError(
            data.path,
            "no inputs given",
            where="--inputs",
            fix=f"Name one or more columns, comma-separated, from: {', '.join(data.columns)}",
        )
    repeated = sorted({i for i in inputs if list(inputs).count(i) > 1})
    if repeated:
        raise DataFileError(
            data.path, f"inputs {repeated} are named twice", where="--inputs", fix="Name each once"
        )
    if output in inputs:
        raise DataFileError(
            data.path,
            f"the output column {output!r} is also among the inputs",
            where="--inputs",
            fix="A model cannot use the displacement it predicts; remove it from --inputs",
        )
    for column in (output, *inputs):
        data.column(column)  # an unknown column names the file's columns
    check_step(data)
    if order != "auto" and not (isinstance(order, int) and 1 <= order <= MAX_ORDER):
        raise DataFileError(
            data.path,
            f"order must be 'auto' or 1..{MAX_ORDER}, got {order!r}",
            where="--order",
            fix="Use --order auto to choose it on held-back data",
        )
    if method not in FIT_METHODS:
        raise DataFileError(
            data.path,
            f"unknown method {method!r}",
            where="--method",
            fix=f"Use one of {', '.join(FIT_METHODS)}",
        )
    for column in inputs:
        if np.ptp(data.column(column)) == 0.0:
            raise DataFileError(
                data.path,
                f"input column {column!r} is constant ({data.column(column)[0]:g}) over the whole "
                "record, so its effect cannot be identified",
                where=f"column {column!r}",
                fix="Leave it out of --inputs, or calibrate on data in which it varies",
            )
    check_units(data, output, inputs)


#: A displacement's name ending in a length unit other than um (or a recorded unit other than
#: um): compd's outputs are in um.
_LENGTH_UNIT = re.compile(r"_(mm|m|nm|cm|in|inch|mil)$", re.IGNORECASE)
#: Machine-tool temperatures in degC lie far below this; kelvin far above it.
_KELVIN_OR_DEGC_SPLIT = 150.0


def check_units(data: DataSet, output: str, inputs: Sequence[str]) -> None:
    """Refuse what a column's name says against what it holds: a constant or non-um output, a
    temperature in kelvin named degC (or the reverse); fitted, each is a model wrong by a factor
    or an offset that no figure of the fit shows."""
    values = data.column(output)
    if np.ptp(values) == 0.0:
        raise DataFileError(
            data.path,
            f"the output column {output!r} is constant ({values[0]:g}) over the whole record: "
            "there is no displacement to model",
            where=f"column {output!r}",
            fix="Name the measured displacement column with --output",
        )
    recorded = data.metadata.get(UNIT_PREFIX + output)
    named = _LENGTH_UNIT.search(output)
    unit = recorded if recorded is not None else (named.group(1) if named else "um")
    if unit not in ("um", "µm", "μm", "-"):
        said = "as the file records it" if recorded is not None else "by its name"
        raise DataFileError(
            data.path,
            f"the output column {output!r} is in {unit} {said}; compd's outputs "
            "(the offsets it writes) are in um, and a fit would take its values as um",
            where=f"column {output!r}",
            fix="Convert it to um in a column named ..._um (e.g. disp_z_um), or rename it if it "
            "already holds um",
        )
    check_input_units(data, inputs)


def check_input_units(data: DataSet, inputs: Sequence[str]) -> None:
    """Refuse a temperature input in kelvin said to be degC, or in degC said to be K (by the file's
    recorded unit, else its name): its reference (the thermal zero a model keeps) would be 273
    degrees off what the daemon reads."""
    for column in inputs:
        unit = column_unit(data, column)
        recorded = UNIT_PREFIX + column in data.metadata
        middle = float(np.median(data.column(column)))
        if unit == "degC" and middle > _KELVIN_OR_DEGC_SPLIT:
            fix = "Subtract 273.15 (it reads kelvin)"
            other = "K"
        elif unit == "K" and middle < _KELVIN_OR_DEGC_SPLIT:
            fix = "Add 273.15 (it reads degC)"
            other = "degC"
        else:
            continue
        said = "as the file records it" if recorded else "by its name"
        fix += (
            f", or record it with the config's 'unit: {other}'"
            if recorded
            else f", or name it {column.rsplit('_', 1)[0]}_{other}"
        )
        raise DataFileError(
            data.path,
            f"input column {column!r} is in {unit} {said}, but its median is {middle:g}: "
            "a machine tool is not that hot or cold, so the unit is likely wrong",
            where=f"column {column!r}",
            fix=fix,
        )


def check_position(
    data: DataSet,
    position: str,
    reference_mm: float,
    output: str,
    inputs: Sequence[str],
    phase_gate: str | None,
) -> None:
    """Refuse a position column the slope cannot be identified from (file, place, fix)."""
    where = f"--position {position}"
    if position == output or position in inputs:
        raise DataFileError(
            data.path,
            f"the position column {position!r} is also the output or an input",
            where=where,
            fix="The position multiplies the slope sub-models; do not list it in --inputs",
        )
    if phase_gate is not None:
        raise DataFileError(
            data.path,
            "--position and --phase-gate together are not supported",
            where=where,
            fix="Fit the feed axis with --position only (its screw heats while it moves)",
        )
    if not np.isfinite(reference_mm):
        raise DataFileError(
            data.path,
            f"the reference position {reference_mm} is not a finite number",
            where="--position-reference-mm",
            fix="Give the position in mm at which the slope term is zero (e.g. 0)",
        )
    values = data.column(position)  # an unknown column names the file's columns
    distinct = np.unique(values)
    if distinct.size < 2:
        raise DataFileError(
            data.path,
            f"column {position!r} holds one position ({distinct[0]:g} mm) over the whole record, "
            "so the slope (um per mm) cannot be told from the offset",
            where=f"column {position!r}",
            fix="Calibrate with measurements at two or more positions along the axis (seed "
            "003: e.g. both ends and the middle), or fit without --position",
        )
