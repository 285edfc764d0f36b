"""Whether a signal's unit is its model input's: the same, or what ``scale`` and ``offset`` make it.

A model is fitted on numbers in the units its file declares
(``signals.<name>.unit``); a config reading a signal in another unit feeds
it numbers off by a factor or an offset, and nothing downstream would
notice. So a unit other than the model's is refused: one compd can
convert linearly is refused with the ``unit``, ``scale`` and ``offset``
that convert it on reading (``value = raw * scale + offset``); any other
is refused as unknown.
"""

from __future__ import annotations

#: unit -> (quantity's unit, factor, offset): ``value_in_quantity_unit = value * factor + offset``.
_LINEAR: dict[str, tuple[str, float, float]] = {
    "degC": ("degC", 1.0, 0.0),
    "°C": ("degC", 1.0, 0.0),
    "C": ("degC", 1.0, 0.0),
    "degF": ("degC", 5.0 / 9.0, -160.0 / 9.0),
    "°F": ("degC", 5.0 / 9.0, -160.0 / 9.0),
    "F": ("degC", 5.0 / 9.0, -160.0 / 9.0),
    "K": ("degC", 1.0, -273.15),
    "um": ("um", 1.0, 0.0),
    "µm": ("um", 1.0, 0.0),
    "μm": ("um", 1.0, 0.0),
    "mm": ("um", 1000.0, 0.0),
    "rpm": ("rpm", 1.0, 0.0),
    "1/min": ("rpm", 1.0, 0.0),
    "min-1": ("rpm", 1.0, 0.0),
    "W": ("kW", 1e-3, 0.0),
    "kW": ("kW", 1.0, 0.0),
    "%": ("%", 1.0, 0.0),
    "percent": ("%", 1.0, 0.0),
    "s": ("s", 1.0, 0.0),
    "ms": ("s", 1e-3, 0.0),
    "bar": ("bar", 1.0, 0.0),
    "Pa": ("bar", 1e-5, 0.0),
}


def unit_problem(unit: str, model_unit: str, scale: float, offset: float) -> tuple[str, str] | None:
    """Why a signal in ``unit`` (read as ``raw * scale + offset``) cannot feed an input in ``model_unit``, and the fix.

    None when the two are the same text.
    """
    if unit == model_unit:
        return None
    if model_unit == "-" and unit in _LINEAR:
        # The file does not say (fitted on a column whose name carried no unit): a config
        # declaring '-' to match would take away the checks its unit gives (a temperature's
        # stuck check), so the fix is the model file's word, not the config's.
        return (
            "the model file does not say which unit it was fitted in",
            f"If it was fitted on {unit!r} values, write it in the model file's 'signals' "
            f"section ({{unit: {unit}}}); else refit on data whose column says its unit "
            "(compd's recordings do). Do not declare 'unit: -' in the config: its unit decides "
            "the signal's checks",
        )
    have, want = _LINEAR.get(unit), _LINEAR.get(model_unit)
    if have is None or want is None or have[0] != want[0]:
        unknown = unit if have is None else model_unit
        why = (
            f"compd does not know {unknown!r}, so it cannot tell whether the two agree"
            if have is None or want is None
            else "they measure different quantities"
        )
        return (
            why,
            f"Read the signal in {model_unit!r}, as the model was fitted, and declare "
            f"'unit: {model_unit}' (scale and offset convert on reading), or fit a model on "
            f"data in {unit!r}",
        )
    # value_model = (value * f_have + o_have - o_want) / f_want, value = raw * scale + offset
    factor = have[1] / want[1]
    new_scale = scale * factor
    new_offset = (offset * have[1] + have[2] - want[2]) / want[1]
    if factor == 1.0 and have[2] == want[2]:
        return (
            f"{unit!r} is {model_unit!r} by another name",
            f"Write 'unit: {model_unit}' as the model does",
        )
    return (
        f"the model would take numbers in {unit} for {model_unit}",
        f"Convert on reading: 'unit: {model_unit}', 'scale: {new_scale:.10g}', "
        f"'offset: {new_offset:.10g}' (value = raw * scale + offset, now in {model_unit})",
    )
