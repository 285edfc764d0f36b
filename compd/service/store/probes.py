"""What the probes taught, on disk: the probe log and each model's learned parameters (a subscriber).

Every probe the loop took (:class:`~compd.service.loop.probemessages.ProbeTaken`) is
appended to the probe log (``compd model updates`` reads it), and the learned
parameters of the running model are written atomically under its sha256, so
they survive a restart (:mod:`compd.files.probestate`). The writes go to a
worker thread, in order: a probe never delays a tick.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Mapping
from pathlib import Path

import structlog

from compd.errors import ModelError
from compd.faultlog import FaultLog
from compd.files.probestate import (
    ProbeRecord,
    append_record,
    reset_learned,
    restore_learners,
    write_learned,
)
from compd.model.probelearner import RESTORE_SKEW_S, SIMULATED_SKEW_S, OutputLearner
from compd.model.probesettings import ProbeSettings
from compd.model.updateprior import Prior
from compd.service.loop.probemessages import ProbeTaken
from compd.service.loop.slots import ModelSlot
from compd.service.loop.snapshot import TickSnapshot

log = structlog.get_logger("compd.service.store")


class ProbeKeeper:
    """Appends each probe to the log and saves the learned parameters, off the loop."""

    name = "probes"

    def __init__(self, state_dir: Path, *, background: bool = True, real_time: bool = True) -> None:
        self.state_dir = state_dir
        self.background = background
        #: A restored time may be this far ahead of the loop's wall clock (s).
        self.skew_s = RESTORE_SKEW_S if real_time else SIMULATED_SKEW_S
        self.fault = FaultLog(log)
        self._writing: asyncio.Future[None] | None = None

    def restore(
        self,
        slot: ModelSlot,
        setups: Mapping[str, tuple[Prior, ProbeSettings]],
        now_unix_s: float = math.nan,
    ) -> dict[str, OutputLearner]:
        """What the probes taught ``slot``'s model before (empty: its priors); a file that cannot
        be read, or holds numbers no update reaches, is set aside (``now_unix_s``: no time after it)."""
        now = now_unix_s if math.isfinite(now_unix_s) else None
        restored = restore_learners(
            self.state_dir, slot.sha256, setups, now_s=now, skew_s=self.skew_s
        )
        if restored.problem is not None:
            log.error(
                "learned probe parameters unreadable: starting from the model's prior",
                model=slot.compiled.name,
                problem=restored.problem,
                set_aside_as=None if restored.set_aside_as is None else str(restored.set_aside_as),
            )
        elif restored.restored:
            log.info("probe updates resumed", model=slot.compiled.name, outputs=restored.restored)
        for output, learner in restored.learners.items():
            if learner.clamped_s > 0.0:
                log.warning(
                    "the saved probe times lay in the future (a clock set back, or a simulation's "
                    "clock ahead of the wall): set to now, so probes fall due from now",
                    model=slot.compiled.name,
                    output=output,
                    ahead_s=round(learner.clamped_s, 1),
                )
        return restored.learners

    def on_tick(self, snapshot: TickSnapshot) -> None:
        probes = snapshot.record.probes
        if not probes:
            return
        if not self.background:
            self.write(probes, snapshot.record.wall_unix_s)
            return
        previous = self._writing

        async def in_order() -> None:
            if previous is not None:
                await previous
            await asyncio.to_thread(self.write, probes, snapshot.record.wall_unix_s)

        self._writing = asyncio.ensure_future(in_order())

    async def finish(self) -> None:
        """Wait for the writes under way (at shutdown)."""
        if self._writing is not None:
            await self._writing

    async def forget(self, sha256: str) -> None:
        """Delete what the probes taught ``sha256``'s model (a reset), after the writes under way:
        one still in flight would write the forgotten parameters back."""
        await self.finish()
        reset_learned(self.state_dir, sha256)

    async def end(self, *, killed: bool) -> None:
        """The last probe's log line and learned parameters on disk (not when killed)."""
        if not killed:
            await self.finish()

    def write(self, probes: tuple[ProbeTaken, ...], now_unix_s: float) -> None:
        try:
            for taken in probes:
                for record in records(taken, now_unix_s):
                    append_record(self.state_dir, record)
                if taken.learned:
                    write_learned(self.state_dir, taken.model_sha256, taken.learned, now_unix_s)
        except (OSError, ModelError) as exc:
            self.fault.failed("cannot write the probe log", error=str(exc))
        else:
            self.fault.cleared("probe log written again")


def records(taken: ProbeTaken, now_unix_s: float) -> list[ProbeRecord]:
    """The probe log's lines of one probe: one per update step, or one saying why it was refused."""
    request = taken.request
    common = {
        "model_sha256": taken.model_sha256,
        "output": taken.output,
        "source": request.source,
        "axis": request.axis,
        "residue_um": request.measured_um if request.measures == "residue" else None,
        "offset_um": taken.offset_um if taken.offset_um == taken.offset_um else None,
        "logged_s": now_unix_s,
    }
    if taken.not_given is not None:  # a resend or a probe too soon: answered, not logged here
        return []
    if taken.refused is not None:
        return [
            ProbeRecord(
                touched_s=request.touched_at_unix_s,
                result="refused",
                measured_um=request.measured_um,
                reason=taken.refused,
                **common,  # type: ignore[arg-type]
            )
        ]
    return [ProbeRecord.of_step(step, **common) for step in taken.steps]  # type: ignore[arg-type]
