"""Waiting for a DriverLink to come back, on the link's own clock, so no test depends on machine speed."""

from __future__ import annotations

import asyncio
from collections.abc import Sequence

from compd.service.loop.clock import VirtualClock
from compd.service.loop.links import DriverLink

#: Link-clock seconds between polls, as ticks would be.
POLL_S = 0.05
#: Polls before giving up: 100 s of the link's clock.
MAX_POLLS = 2000


async def seconds_until_read(link: DriverLink, clock: VirtualClock, points: Sequence[str]) -> float:
    """Poll ``link`` every :data:`POLL_S` of ``clock`` (its backoff's clock) until it reads again.

    Returns the link-clock seconds that took: the retries the link's backoff
    made, not how long a busy machine took to run them.
    """
    start = clock.now()
    for _ in range(MAX_POLLS):
        if await link.read(points):
            return clock.now() - start
        while link.connecting:
            # An attempt under way is real I/O (a handshake takes longer on a busy host): the
            # link's clock stands still meanwhile, so only its backoff is counted. The link's
            # own timeout_s (real time) ends the attempt: this never waits unbounded.
            await asyncio.sleep(0.005)
        clock.advance(POLL_S)
        await asyncio.sleep(0)
    raise AssertionError(f"no reconnect within {MAX_POLLS * POLL_S:g} s of the link's clock")
