"""The gateway's status byte watched: the ok bit read, the live bit's toggles timed.

Fed by a transport with every fresh sample of the status byte and checked
by the driver after each read; ages are bus time (monotonic seconds).
"""

from __future__ import annotations

import time

from compd.drivers.gateway.image import frame_of
from compd.drivers.gateway.settings import FRAME_BYTES, GatewaySettings
from compd.errors import DriverProtocolError, DriverTimeoutError


class StatusWatch:
    """The gateway's status byte: ok bit and live-bit toggles, fed with every new sample."""

    def __init__(self, settings: GatewaySettings) -> None:
        self.status = settings.status
        self.live_timeout_s = settings.live_timeout_s
        self.reset(time.monotonic())

    def reset(self, now_s: float) -> None:
        self.byte: int | None = None
        self._live: int | None = None
        self.toggled_at_s = self.sampled_at_s = now_s

    def observe(self, byte: int, now_s: float) -> None:
        """One fresh sample of the status byte, received at ``now_s``."""
        if now_s - self.sampled_at_s > self.live_timeout_s:
            # After a silence (judged by the frames' age, not here) the first
            # sample starts a new watch: its bit may equal the last one by chance.
            self._live = None
        self.byte, self.sampled_at_s = byte, now_s
        if self.status is not None and self.status.live_bit is not None:
            live = (byte >> self.status.live_bit) & 1
            if live != self._live:
                self._live, self.toggled_at_s = live, now_s

    def check(self, now_s: float, where: str, fresh: frozenset[int] | None) -> None:
        """Raise if the gateway says its DP side is down, or is frozen.

        Only while the status byte is fresh: a silent gateway is told by its
        frames' age (stale, then DriverTimeoutError), not by its live bit.
        """
        s = self.status
        if s is None or (fresh is not None and frame_of(s.offset, FRAME_BYTES) not in fresh):
            return
        if s.ok_bit is not None and self.byte is not None and not (self.byte >> s.ok_bit) & 1:
            raise DriverProtocolError(
                f"gateway {where}: Profibus side not in data exchange (ok bit {s.ok_bit} of "
                f"status byte {s.offset} is clear): check the DP master and the gateway's DP link"
            )
        if s.live_bit is not None and now_s - self.toggled_at_s > self.live_timeout_s:
            raise DriverTimeoutError(
                f"gateway {where}: live bit {s.live_bit} of status byte {s.offset} has not "
                f"toggled for {now_s - self.toggled_at_s:.2f} s (> live_timeout_s "
                f"{self.live_timeout_s:g}): the gateway is frozen"
            )
