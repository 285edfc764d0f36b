"""The state saver as the loop's subscriber: the model's state on disk every few ticks, off the loop."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path
from typing import Any

import structlog

from compd.faultlog import FaultLog
from compd.service.loop.snapshot import TickSnapshot
from compd.service.store.state import SavedState, save_state

log = structlog.get_logger("compd.service.store")


class StateSaver:
    """Saves ``taken()`` into ``state_dir`` every ``every_ticks`` ticks and at shutdown.

    fsync takes milliseconds on an SD card or a busy disk: the state is taken
    between ticks and written by a worker thread, so a save never delays a
    tick; a save still running is not overtaken. ``background=False`` writes
    inside the tick instead: deterministic on a virtual clock, where a
    thousand ticks pass during one real fsync. Saves that fail (every few
    ticks while the disk is full) are one fault episode.
    """

    name = "state"

    def __init__(
        self,
        state_dir: Path,
        taken: Callable[[], SavedState | None],
        *,
        every_ticks: int,
        background: bool = True,
    ) -> None:
        self.state_dir = state_dir
        self.taken = taken
        self.every_ticks = every_ticks
        self.background = background
        self.fault = FaultLog(log)
        #: Why the last save failed, while saves fail (``fault.active``); None while they succeed.
        self.error: str | None = None
        self._saving: asyncio.Future[None] | None = None

    def on_tick(self, snapshot: TickSnapshot) -> None:
        if snapshot.ticks % self.every_ticks == 0:
            self.save_soon()

    def save_soon(self) -> None:
        """Save the state as it is now: in a worker thread (or here, without ``background``)."""
        if self._saving is not None and not self._saving.done():
            return
        saved = self.taken()
        if saved is None:
            return
        if self.background:
            self._saving = asyncio.ensure_future(asyncio.to_thread(self.write, saved))
        else:
            self.write(saved)

    async def finish(self) -> None:
        """Wait for a save under way (before the last one, at shutdown)."""
        if self._saving is not None:
            await self._saving

    async def end(self, *, killed: bool) -> None:
        """The save under way, then the last one (not when killed)."""
        if not killed:
            await self.finish()
            self.save_now()

    def save_now(self) -> None:
        """Save in the calling thread (at shutdown)."""
        saved = self.taken()
        if saved is not None:
            self.write(saved)

    def write(self, saved: SavedState) -> None:
        directory = str(self.state_dir)
        try:
            save_state(self.state_dir, saved)
        except OSError as exc:
            self.error = str(exc)
            self.fault.failed("cannot save state", error=self.error, directory=directory)
        else:
            self.error = None
            self.fault.cleared("state saved again", directory=directory)

    def status(self) -> dict[str, Any]:
        """``compd status``'s ``state``: where it is saved and, while saves fail, why.

        A failing save does not stop compensation, but a restart then resumes
        from an older state (or none): the operator must hear of it beside the
        offsets, not only once in the journal.
        """
        return {
            "directory": str(self.state_dir),
            "saving": self.error is None,
            "error": self.error,
            "failed_episodes": self.fault.episodes,
        }

    def problem(self) -> str | None:
        """One line while saves fail (``/healthz``'s warnings, systemd's status); None while they work."""
        if self.error is None:
            return None
        return f"state not saved in {self.state_dir} ({self.error}): a restart resumes from an older state"
