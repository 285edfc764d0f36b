"""A simulated run on virtual time saves its state once, at the end: no fsync per tick for a file the next run drops."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from compd.files.yamlplace import resolve_path
from compd.service.config.loading import load_config
from compd.service.store.state import STATE_FILE
from compd.sim.plc.run import run_simulation, saved_at_end_only
from tests.ports import free_port


def _config(tmp_path: Path, hours: float):
    """The quick start's config, ``hours`` long, saving every 10 ticks, its files under ``tmp_path``."""
    return load_config(
        resolve_path("bundled:simulated.yaml", Path(".")),
        [
            f"drivers.plc.settings.port={free_port()}",
            f"simulation.hours={hours}",
            f"state.directory={tmp_path / 'state'}",
            "state.save_every_ticks=10",
            "recorder.enabled=false",
        ],
    )


def test_on_virtual_time_the_state_is_written_at_the_end_only(tmp_path: Path) -> None:
    """No state file while the 180 ticks run (save_every_ticks 10 notwithstanding); the last tick's after."""
    config = _config(tmp_path, 0.05)
    seen: list[bool] = []
    result = asyncio.run(
        run_simulation(
            config, on_tick=lambda *_: seen.append((config.state_dir / STATE_FILE).exists())
        )
    )
    assert len(seen) == 181 and not any(seen)
    saved = json.loads((config.state_dir / STATE_FILE).read_text())
    assert saved["ticks"] == result.status["counters"]["ticks"] == 181


def test_only_the_save_period_changes(tmp_path: Path) -> None:
    """What a run on virtual time runs is the config as given, but for ``state.save_every_ticks``."""
    config = _config(tmp_path, 0.05)
    changed = saved_at_end_only(config)
    assert changed.doc.state.save_every_ticks > 10**12
    assert changed.doc.model_copy(update={"state": config.doc.state}) == config.doc
    assert changed.state_dir == config.state_dir and changed.path == config.path
