"""How a daemon describes itself: its telemetry identity, its recordings' metadata."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from compd import __version__
from compd.service.config.metricunits import prometheus_unit

if TYPE_CHECKING:
    from compd.service.config.loading import Config
    from compd.service.loop.slots import ModelSlot


def identity(config: Config, slot: ModelSlot | None, started_unix_s: float) -> dict[str, Any]:
    """The telemetry birth's description of this daemon: model (None: a data logger), signals, axes, period."""
    doc = config.doc
    return {
        "model": None if slot is None else {"name": slot.compiled.name, "sha256": slot.sha256},
        "period_s": doc.period_s,
        "started": started_unix_s,
        "signals": {n: _signal(s.unit, s.description) for n, s in doc.signals.items()},
        # The status's numbers are in engineering units: each input's its signal's, the rest um.
        "units": {"inputs": "signals.<name>.unit", "model_outputs": "um", "offsets": "um"},
        "health_codes": {"ok": 0, "held": 1, "faulted": 2, "estimated": 3},
        "axes": {
            axis: {"model_output": out.model_output, "max_offset_um": out.max_offset_um}
            for axis, out in doc.outputs.items()
        },
    }


def _signal(unit: str, description: str) -> dict[str, Any]:
    """A signal in the birth: its unit, and the Prometheus metric carrying it (value x factor)."""
    suffix, factor = prometheus_unit(unit)
    metric = {"name": f"compd_signal_{suffix}", "factor": factor}
    return {"unit": unit, "description": description, "metric": metric}


def recording_metadata(config: Config) -> dict[str, str]:
    """What every recording says about where it comes from (the model is added per file)."""
    metadata = {"compd_version": __version__, "config": str(config.path)}
    if config.doc.machine_id is not None:
        metadata = {"machine_id": config.doc.machine_id, **metadata}
    return metadata


#: Units of the columns the daemon adds to a recording's signals, by name or by prefix.
_COLUMN_UNITS = {"t_s": "s", "status": "bits", "heartbeat": "count"}
_PREFIX_UNITS = {
    "health": "0 ok, 1 held, 2 faulted, 3 estimated",
    "model": "um",
    "offset": "um",
}
_PREFIX_UNITS |= {"readback": "um", "gain": "1", "probe": "um"}
#: A simulated run's truth (``sim.residue.<axis>_um``, added by :mod:`compd.sim.plc.run`).
_PREFIX_UNITS |= {"sim": "um"}


def column_units(config: Config) -> Callable[[str], str | None]:
    """Each recorded column's unit: a signal's from the config, the daemon's own by name."""
    signals = {name: signal.unit for name, signal in config.doc.signals.items()}

    def unit(column: str) -> str | None:
        if column in signals:
            return signals[column] or None
        prefix, dot, rest = column.partition(".")
        if prefix == "read" and dot:  # what a signal read, in its own unit
            return signals.get(rest) or None
        return _PREFIX_UNITS.get(prefix) if dot else _COLUMN_UNITS.get(column)

    return unit
