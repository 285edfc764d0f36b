"""One frame of ``compd run``'s live view: where the run is, every input, every axis.

Shared by the run against a real machine and the simulated one (which adds
the twin's true error to each axis). Each axis column says which quantity and
which sign it shows: the model's output is the drift it predicts; the offset
written is ``sign x`` that drift (the output's ``sign`` in the config), after
the safety stage's clamp and slew limit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from rich.console import Console, Group, RenderableType
from rich.table import Table
from rich.text import Text

from compd.service.loop.compensator import TickRecord
from compd.service.loop.safety import Level
from compd.service.loop.signals import Health

HEALTH_STYLE = {
    Health.OK: "green",
    Health.HELD: "yellow",
    Health.ESTIMATED: "magenta",
    Health.FAULTED: "bold red",
}
LEVEL_STYLE = {Level.OK: "green", Level.DEGRADED: "yellow", Level.FAULTED: "bold red"}

#: The axis columns every view has, each naming its quantity and sign.
AXIS_COLUMNS = ("axis", "model drift um", "sign", "offset written um (sign x drift, limited)")


def level_text(record: TickRecord) -> Text:
    """The status word's level, coloured."""
    level = Level(record.status & 0b11)
    return Text(level.name.lower(), LEVEL_STYLE[level])


def hms(seconds: float) -> str:
    """``H:MM:SS`` of a duration."""
    s = int(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


def progress(t_s: float, duration_s: float | None) -> str:
    """``t 0:05:00 / 0:10:00 (50 %)`` up to where the run stops, or ``t 0:05:00`` with no end."""
    if duration_s is None:
        return f"t {hms(t_s)}"
    done_pct = 100.0 * min(t_s / duration_s, 1.0) if duration_s > 0 else 100.0
    return f"t {hms(t_s)} / {hms(duration_s)} ({done_pct:.0f} %)"


def tick_view(
    head: Text,
    record: TickRecord,
    units: Mapping[str, str],
    signs: Mapping[str, int | float],
    counters: Mapping[str, int],
    extra_axis_columns: Mapping[str, Mapping[str, str]] | None = None,
    *,
    narrow: bool = False,
) -> RenderableType:
    """``head``, the inputs with units and health, the axes, the counters.

    ``extra_axis_columns``: more columns of the axis table, ``{title: {axis: text}}``.
    ``narrow``: the axis titles in two lines (80 columns), so the header is two lines, not three.
    """
    inputs = Table(box=None, pad_edge=False, header_style="bold")
    inputs.add_column("input")
    inputs.add_column("value", justify="right")
    inputs.add_column("health")
    for name, value in record.values.items():
        health = record.health[name]
        reason = record.reasons.get(name, "")
        inputs.add_row(
            name,
            f"{value:.3f} {units.get(name, '')}",
            Text(health.name.lower() + (f" ({reason})" if reason else ""), HEALTH_STYLE[health]),
        )
    extra = extra_axis_columns or {}
    axes = Table(box=None, pad_edge=False, header_style="bold")
    axes.add_column(AXIS_COLUMNS[0])
    for column in (*AXIS_COLUMNS[1:], *extra):
        axes.add_column(_two_lines(column) if narrow else column, justify="right")
    for axis, offset_um in record.offsets_um.items():
        sign = signs.get(axis, 1)
        # The record's target is sign x the model's output, so the drift is target x sign (sign ±1).
        drift_um = record.targets_um.get(axis, float("nan")) * sign
        axes.add_row(
            axis,
            f"{drift_um:+.2f}",
            f"{sign:+g}",
            _written(offset_um, record.acknowledged_um.get(axis)),
            *(column.get(axis, "") for column in extra.values()),
        )
    shown = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in counters.items())
    return Group(head, inputs, axes, Text(shown, "dim"))


def _written(offset_um: float, acknowledged_um: float | None) -> Text:
    """The offset, or "not written" in red where the device acknowledged nothing this tick."""
    if acknowledged_um is None or not math.isnan(acknowledged_um):
        return Text(f"{offset_um:+.2f}")
    return Text(f"not written ({offset_um:+.2f})", "bold red")


def _two_lines(title: str) -> str:
    """``title`` broken before its last word, or before its parenthesis."""
    if "(" in title:
        return title.replace(" (", "\n(", 1)
    return "\n".join(title.rsplit(" ", 1))


def too_wide(console: Console, renderable: RenderableType) -> bool:
    """Whether ``renderable`` at its natural width is wider than ``console``."""
    unbounded = console.options.update_width(100_000)  # a measure is clamped to the width given
    return console.measure(renderable, options=unbounded).maximum > console.width
