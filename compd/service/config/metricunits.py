"""A signal's unit as Prometheus names it: one metric per physical quantity, in its base unit.

Prometheus asks for base units in metric names (seconds, meters, celsius,
watts, ratios 0-1) and one unit per metric, so a query never adds degC to
kW. A config's ``unit`` is free text; :func:`prometheus_unit` maps the usual
ones to ``(metric suffix, factor)``, ``value_in_base_unit = value * factor``.
Speeds stay revolutions (per second): Prometheus has no base unit for them,
and hertz would hide that this is a spindle's speed. A unit not in
:data:`UNITS` keeps its own name, made a valid metric name
(``l/min`` -> ``compd_signal_l_min``), with factor 1: still one metric per
unit, never a mix.
"""

from __future__ import annotations

import re

#: Config unit -> (metric suffix, factor to the base unit).
UNITS: dict[str, tuple[str, float]] = {
    "degC": ("celsius", 1.0),
    "°C": ("celsius", 1.0),
    "C": ("celsius", 1.0),
    "K": ("kelvin", 1.0),
    "rpm": ("revolutions_per_second", 1.0 / 60.0),
    "1/min": ("revolutions_per_second", 1.0 / 60.0),
    "W": ("watts", 1.0),
    "kW": ("watts", 1e3),
    "um": ("meters", 1e-6),
    "mm": ("meters", 1e-3),
    "m": ("meters", 1.0),
    "%": ("ratio", 0.01),
    "percent": ("ratio", 0.01),
    "s": ("seconds", 1.0),
    "ms": ("seconds", 1e-3),
    "Pa": ("pascals", 1.0),
    "bar": ("pascals", 1e5),
    "V": ("volts", 1.0),
    "A": ("amperes", 1.0),
}


def prometheus_unit(unit: str) -> tuple[str, float]:
    """The metric suffix and the factor to it for a config's ``unit`` (``"kW"`` -> ``("watts", 1000.0)``)."""
    if unit in UNITS:
        return UNITS[unit]
    suffix = re.sub(r"[^a-z0-9]+", "_", unit.lower()).strip("_")
    return (suffix or "value", 1.0)
