"""``compd status`` marks an offset the last tick did not write, and says why (the PLC's link down)."""

from __future__ import annotations

import asyncio
from pathlib import Path

from compd.cli.status import offset_line, tick_line
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.notify import SystemdNotifier

from .daemon_setup import notify_socket, run, status_lines, write_config


def _with_outage(tmp_path: Path, duration_s: float):
    """The bundled simulated config with its output on a second PLC that drops from 150 s to 180 s."""
    drop = {"kind": "drop", "start_s": 150, "duration_s": 30}
    plc = {
        "type": "simulated",
        "settings": {"data": "bundled:example_spectrum.csv", "faults": [drop]},
    }
    config = write_config(
        tmp_path,
        {
            "drivers": {"machine": {"settings": {"start_s": 7200}}, "plc": plc},
            "outputs": {"Y": {"driver": "plc"}},
            "status": {"driver": "plc"},
        },
    )
    return run(config, duration_s)


def test_during_a_plc_outage_the_offset_is_marked_not_written(tmp_path: Path) -> None:
    """Inside the drop the status answer names the axis and its link; the line says "not written: plc link
    down", and the tick's line the word's level: "status word 65 (degraded)"."""
    service, records = _with_outage(tmp_path, 165.0)
    assert not records[-1].written
    reply = service.status()
    assert reply["offsets_not_written"] == {"Y": "plc link down"}
    assert f"status word {reply['status_word']} (degraded)  heartbeat" in tick_line(reply)
    line = offset_line("Y", reply)
    assert line.startswith(
        f"  offset Y: {reply['offsets_um']['Y']:+.3f} um (not written: plc link down; target"
    )


def test_once_the_link_is_back_the_mark_is_gone(tmp_path: Path) -> None:
    """After the drop the offset is written again: no mark, the usual line."""
    service, records = _with_outage(tmp_path, 240.0)
    assert records[-1].written
    reply = service.status()
    assert reply["offsets_not_written"] == {}
    assert "not written" not in offset_line("Y", reply) and "target" in offset_line("Y", reply)


def test_systemds_status_line_marks_the_offset_not_written_and_says_degraded(
    tmp_path: Path,
) -> None:
    """Inside the drop the line ``systemctl status`` shows reads "Y ... um not written; status word
    N (degraded)"; after it, "(ok)" with no mark."""
    config = write_config(
        tmp_path,
        {
            "drivers": {
                "machine": {"settings": {"start_s": 7200}},
                "plc": {
                    "type": "simulated",
                    "settings": {
                        "data": "bundled:example_spectrum.csv",
                        "faults": [{"kind": "drop", "start_s": 150, "duration_s": 30}],
                    },
                },
            },
            "outputs": {"Y": {"driver": "plc"}},
            "status": {"driver": "plc"},
            "live_every_ticks": 1,
        },
    )
    lines: list[str] = []
    with notify_socket() as (sock, path):
        service = Service(
            config,
            clock=VirtualClock(),
            control=False,
            notifier=SystemdNotifier({"NOTIFY_SOCKET": path}),
            on_tick=lambda record: lines.extend(status_lines(sock)),
        )
        asyncio.run(service.run(duration_s=240.0))
    during = lines[165 - 1]
    assert during.startswith("Y ") and " um not written; status word " in during, during
    assert "(degraded)" in during, during  # the PLC's link down: offsets not getting through
    assert "; status word 0 (ok)" in lines[-1] and "not written" not in lines[-1], lines[-1]
