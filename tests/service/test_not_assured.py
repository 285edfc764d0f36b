"""An input whose wrong reading the sensors cannot see within its axis's tolerance is said where an
operator looks for "all well": ``/healthz``'s warnings and systemd's status line, not only in
``compd status``'s yellow lines, while the status word's level reads ok."""

from __future__ import annotations

import asyncio
from pathlib import Path

from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.notify import SystemdNotifier

from .daemon_setup import notify_socket, status_lines, write_config
from .test_probing import EVERY_TICKS, probed_run

#: The default test config's model (example_gated_arx.yaml, no consistency model): nothing checks
#: its two temperatures against the other sensors, and each moves Y by more than 5 um unseen.
NOT_ASSURED = (
    "not assured on Y: T_shopfloor_degC, T_spindle_degC not verifiable to its 5 um tolerance"
)


def test_inputs_nothing_verifies_are_said_by_healthz_and_systemds_line(tmp_path: Path) -> None:
    """Level ok, yet the warnings and systemd's line say which inputs on which axis are not
    verifiable to the axis's tolerance."""
    lines: list[str] = []
    with notify_socket() as (sock, path):
        service = Service(
            write_config(tmp_path, {"live_every_ticks": 10}),
            clock=VirtualClock(),
            control=False,
            notifier=SystemdNotifier({"NOTIFY_SOCKET": path}),
            on_tick=lambda record: lines.extend(status_lines(sock)),
        )
        asyncio.run(service.run(duration_s=30.0))
    assert service.status()["status_word"] == 0  # the level: ok
    rows = [r for r in service.status()["unverifiable"] if not r["verifiable"]]
    assert {r["input"] for r in rows} == {"T_spindle_degC", "T_shopfloor_degC"}, rows
    assert service.not_assured() == [NOT_ASSURED]
    assert lines and lines[-1].endswith(f"; status word 0 (ok): {NOT_ASSURED}"), lines


def test_two_probes_in_a_row_not_taken_are_said_by_healthz_and_systemds_line(
    tmp_path: Path,
) -> None:
    """A probe 50 um off, then one 50 um off the other way a probe gap later (2 h, 4 h): neither is
    taken, the probes disagree with the model, and the warnings say so for Z to the shift's end."""
    run = probed_run(tmp_path, {EVERY_TICKS: 50.0, 2 * EVERY_TICKS: -50.0})
    assert run.service.probing is not None and run.service.probing.disagrees("Z")
    assert (
        "not assured on Z: two probes in a row not taken: the model no longer describes the machine"
        in run.service.not_assured()
    )
