"""The LinuxCNC driver against a helper that answers with well-formed JSON of the wrong shape.

A fake helper (:mod:`tests.drivers.fake_hal_helper`) stands in for the HAL
side, so these tests need no LinuxCNC: the driver must check every reply
line against the helper's protocol and raise only compd's DriverError
family, and the daemon must go on compensating through any of them.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from structlog.testing import capture_logs

from compd.drivers.linuxcnc import LinuxCncDriver, LinuxCncSettings
from compd.errors import DriverError, DriverProtocolError
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock

from ..service.daemon_setup import write_config
from .fake_hal_helper import install

ASKED = ["T-spindle-degC", "axis.z"]
#: The reply lines issue 22 found crashing ``compd run``.
CRASHERS = ["[]", "1", "{}", '{"ok": "abc"}', '{"ok": {"axis.z": "x"}}']

_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=8,
)
#: Reply lines that parse (or nearly: nesting deeper than any parser's limit) but are no valid answer.
wrong_replies = st.one_of(
    _json.map(json.dumps),
    _json.map(lambda v: json.dumps({"ok": v})),
    st.dictionaries(st.sampled_from([*ASKED, "unasked"]), _json, max_size=3).map(
        lambda values: json.dumps({"ok": values})
    ),
    st.fixed_dictionaries({"ok": _json}, optional={"error": _json, "kind": _json}).map(json.dumps),
    st.fixed_dictionaries({"error": _json}, optional={"kind": _json}).map(json.dumps),
    st.integers(1, 60_000).map(lambda depth: "[" * depth),
    st.integers(1, 30_000).map(lambda depth: "[" * depth + "]" * depth),
    st.sampled_from(CRASHERS),
)


def make_driver(python: Path) -> LinuxCncDriver:
    return LinuxCncDriver(LinuxCncSettings(python=str(python)), now=time.monotonic, base_dir=Path())


def test_wrong_replies_raise_only_driver_errors(tmp_path):
    """Whatever JSON the helper answers, a read gives floats for asked addresses, a write None, or both DriverError."""
    python, replies = install(tmp_path, ["{}"])
    driver = make_driver(python)
    with asyncio.Runner() as runner:
        runner.run(driver.open())

        @settings(max_examples=60, deadline=None)
        @given(reply=wrong_replies, write=st.booleans())
        def check(reply: str, write: bool) -> None:
            replies.write_text(reply + "\n")
            if driver.helper_pid is None:  # a reply over the line limit ended the last helper
                runner.run(driver.open())
            try:
                if write:
                    assert runner.run(driver.write({"axis.z": 5.0})) is None
                else:
                    values = runner.run(driver.read(ASKED))
                    assert set(values) <= set(ASKED)
                    assert all(type(v) is float for v in values.values())
            except DriverError:
                pass

        try:
            check()
        finally:
            runner.run(driver.close())


@pytest.mark.parametrize("reply", CRASHERS)
def test_each_reply_that_crashed_compd_run_is_a_protocol_error(tmp_path, reply):
    """The replies that crashed ``compd run`` are DriverProtocolErrors that quote the reply."""
    python, _ = install(tmp_path, [reply])
    driver = make_driver(python)

    async def read() -> None:
        await driver.open()
        try:
            await driver.read(ASKED)
        finally:
            await driver.close()

    with pytest.raises(
        DriverProtocolError, match=r"the HAL helper's reply .* is not a reply to read"
    ):
        asyncio.run(read())


def test_the_daemon_compensates_on_through_wrong_replies(tmp_path):
    """A daemon whose offset goes through the helper runs its span through wrong replies, one ERROR per episode."""
    good_read, good_write = json.dumps({"ok": {"axis.z": 0}}), json.dumps({"ok": None})
    python, _ = install(tmp_path, [*CRASHERS, good_read, good_write, "[" * 50_000])
    config = write_config(
        tmp_path,
        {
            "drivers": {"mill": {"type": "linuxcnc", "settings": {"python": str(python)}}},
            "outputs": {
                "Y": {
                    "driver": "mill",
                    "address": "axis.z",
                    "encoding": {"type": "int", "scale": 10},
                }
            },
        },
    )
    service = Service(config, clock=VirtualClock(), control=False, background_saves=False)
    with capture_logs() as logs:
        asyncio.run(service.run(duration_s=120.0))
    link = service.links["mill"]
    assert service.compensator.counters.ticks >= 100
    assert link.faults >= 1
    started = [e for e in logs if e["log_level"] == "error" and e.get("driver") == "mill"]
    assert len(started) == link.faults
