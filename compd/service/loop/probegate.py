"""Which probes reach the update: each one once, and one per axis per probe gap.

A probe changes the running model, so a request that comes again must not
change it again (HTTP's idempotency keys, Kafka's producer ids): a resend of
a probe already taken (same axis, source, touch time, value and sense) is
answered with what the update did the first time, and not given to it again.
And one probe per axis is given to the update per ``min_gap_s`` of touch time
(default 900 s, the simulated PLC's ``min_gap_h``: a probe cycle at the next
tool change): a retry of ``compd model probe`` (its touch is when it arrives),
a flood on the control socket, or a flagged probe "confirmed" by the same
touch resent are refused, so a confirmation is a separate touch at least
that much later, and a flood moves the model by at most what one probe may.
Touches before the last one taken go on to the update, which refuses them
for their order (a gauge result typed in late names its own touch).

Each refusal is answered; the log says it once per episode (WARNING at the
first, DEBUG after, INFO with the count when a probe is taken again), as it
does for probes refused as they arrive (a value beyond physics, a full queue).
"""

from __future__ import annotations

import math
from collections import OrderedDict

import structlog

from compd.service.loop.probemessages import DUPLICATE, TOO_SOON, ProbeRequest, ProbeTaken

log = structlog.get_logger("compd.service.loop.probing")

#: The probe gap by default (s): one probe per axis given to the update per this much touch time.
DEFAULT_MIN_GAP_S = 900.0
#: A PLC that keeps the gap itself stamps its touch on its own clock: this much less is the gap.
GAP_SLACK_S = 1.0
#: The probes remembered to answer a resend (the newest; a few shifts of probe cycles).
KEEP = 256


class ProbeGate:
    """Screens each probe before the update: :meth:`screen`, then :meth:`remember` what was done."""

    def __init__(self, min_gap_s: float = DEFAULT_MIN_GAP_S, keep: int = KEEP) -> None:
        self.min_gap_s = min_gap_s
        self.keep = keep
        self._seen: OrderedDict[tuple[object, ...], ProbeTaken] = OrderedDict()
        #: Per (axis, duplicate/too_soon): refusals in the episode under way.
        self._episodes: dict[tuple[str, str], int] = {}

    def screen(
        self, request: ProbeRequest, sha256: str, output: str, last_touch_s: float | None
    ) -> ProbeTaken | None:
        """The answer for a probe not to give to the update (a resend, too soon); None: give it."""
        original = self._seen.get(_key(request))
        if original is not None:
            why = (
                f"already taken (the same probe from {request.source}, touched at "
                f"{request.touched_at_unix_s:.1f}): {original.result} the first time, "
                "not taken again"
            )
            return self._refuse(request, sha256, output, DUPLICATE, why, original)
        touched = request.touched_at_unix_s
        gap_s = self.min_gap_s - GAP_SLACK_S
        if last_touch_s is not None and last_touch_s <= touched < last_touch_s + gap_s:
            why = (
                f"touched {touched - last_touch_s:.0f} s after the last probe of "
                f"{request.axis} given to the update: one is taken per {self.min_gap_s:g} s of "
                "touch time (probes.min_gap_s); a confirmation needs a separate touch that much "
                "later, not taken"
            )
            return self._refuse(request, sha256, output, TOO_SOON, why, None)
        return None

    def remember(self, taken: ProbeTaken) -> None:
        """A probe the update saw (taken or refused by it): a resend is answered with it."""
        self._seen[_key(taken.request)] = taken
        self._seen.move_to_end(_key(taken.request))
        while len(self._seen) > self.keep:
            self._seen.popitem(last=False)
        axis = taken.request.axis
        for kind in (DUPLICATE, TOO_SOON, "refused"):
            count = self._episodes.pop((axis, kind), 0)
            if count:
                log.info(f"probes refused ({kind}) until this one", axis=axis, refused=count)

    def refused_at_once(self, request: ProbeRequest, why: str) -> None:
        """A probe refused as it arrived (beyond physics, a full queue): logged once per episode."""
        self._note(request, "refused", why)

    def forget(self) -> None:
        """After a reset: a probe taken before it may be given again."""
        self._seen.clear()

    def _note(self, request: ProbeRequest, kind: str, why: str) -> None:
        """WARNING at an episode's first refusal of this kind on this axis, DEBUG after."""
        episode = (request.axis, kind)
        count = self._episodes.get(episode, 0)
        self._episodes[episode] = count + 1
        say = log.debug if count else log.warning
        say(f"probe refused ({kind})", axis=request.axis, source=request.source, reason=why)

    def _refuse(
        self,
        request: ProbeRequest,
        sha256: str,
        output: str,
        kind: str,
        why: str,
        original: ProbeTaken | None,
    ) -> ProbeTaken:
        self._note(request, kind, why)
        return ProbeTaken(
            request,
            sha256,
            output,
            math.nan,
            math.nan,
            refused=why,
            not_given=kind,
            original=original,
        )


def _key(request: ProbeRequest) -> tuple[object, ...]:
    return (*request.key(), request.accept_shift)
