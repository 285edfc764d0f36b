"""How a daemon describes itself: its telemetry identity, its recordings' metadata, its systemd status line."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from compd import __version__

if TYPE_CHECKING:
    from compd.service.compensator import TickRecord
    from compd.service.config import Config
    from compd.service.slots import ModelSlot


def identity(config: Config, slot: ModelSlot | None, started_unix_s: float) -> dict[str, Any]:
    """The telemetry birth's description of this daemon: model (None: a data logger), signals, axes, period."""
    doc = config.doc
    return {
        "model": None if slot is None else {"name": slot.compiled.name, "sha256": slot.sha256},
        "period_s": doc.period_s,
        "started": started_unix_s,
        "signals": {
            n: {"unit": s.unit, "description": s.description} for n, s in doc.signals.items()
        },
        "axes": {
            axis: {"model_output": out.model_output, "max_offset_um": out.max_offset_um}
            for axis, out in doc.outputs.items()
        },
    }


def recording_metadata(config: Config) -> dict[str, str]:
    """What every recording says about where it comes from (the model is added per file)."""
    metadata = {"compd_version": __version__, "config": str(config.path)}
    if config.doc.machine_id is not None:
        metadata = {"machine_id": config.doc.machine_id, **metadata}
    return metadata


def systemd_summary(record: TickRecord) -> str:
    """One line for ``systemctl status``: offsets and the status level."""
    offsets = ", ".join(f"{axis} {value:+.2f} um" for axis, value in record.offsets_um.items())
    return f"{offsets}; status word {record.status}"
