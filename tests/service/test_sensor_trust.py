"""``compd sensor trust NAME``: the socket's ``sensor`` request reaches the plausibility check and says what it did."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from compd.errors import CompdError
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from tests.service.test_verifiable import config


def test_a_sensor_request_names_the_signal_and_what_it_did(tmp_path: Path) -> None:
    """Before the check runs nothing stands in; an unknown name or a malformed request is refused with the fix."""
    service = Service(config(tmp_path), clock=VirtualClock(), control=False)
    reply = asyncio.run(service.trust_sensor({"trust": "T_column_front_degC"}))
    assert reply == {
        "signal": "T_column_front_degC",
        "answer": "T_column_front_degC: no consistency check runs, so nothing stands in for it",
    }
    with pytest.raises(CompdError, match="there is no signal 'T_nowhere'"):
        asyncio.run(service.trust_sensor({"trust": "T_nowhere"}))
    with pytest.raises(CompdError, match='"trust": "SIGNAL_NAME"'):
        asyncio.run(service.trust_sensor({"trust": 3}))


def test_the_command_line_parses_sensor_trust() -> None:
    """``compd sensor trust NAME --config FILE`` is a command of its own, with the daemon's --config."""
    from compd.cli import build_parser

    args = build_parser("compd.cli.sensor").parse_args(
        ["sensor", "trust", "T_spindle_degC", "--config", "c.yaml"]
    )
    assert (args.action, args.name, args.config) == ("trust", "T_spindle_degC", "c.yaml")
