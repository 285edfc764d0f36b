"""A probe as it reaches the loop and as the loop took it: plain records, no model code.

The control socket, MQTT and the PLC's probe registers build a
:class:`ProbeRequest`; :class:`~compd.service.loop.probing.ProbeLearning`
turns it into a :class:`ProbeTaken`, which the recorder, the status page and
the state directory read. They live apart from the learning so that a daemon
without probes never imports the update's numerics (about 1.4 MB resident).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from compd.errors import CompdError
from compd.service.loop.points import SignalPoint

if TYPE_CHECKING:
    from compd.model.probeupdate import ProbeStep

Measures = Literal["residue", "thermal_error"]
#: What the loop answers for a probe it did not give to the update: a resend of one it took
#: (same source, touch and value), or one touched within ``probes.min_gap_s`` of the last.
DUPLICATE, TOO_SOON = "duplicate", "too_soon"


@dataclass(frozen=True)
class ProbeRequest:
    """One measurement of an axis: ``measured_um`` at ``touched_at_unix_s``, from ``source``."""

    axis: str
    measured_um: float
    touched_at_unix_s: float
    source: str
    measures: Measures = "residue"
    #: The PLC's counter value for a probe read from registers.
    count: int | None = None
    #: A person says the machine moved (``compd model probe --accept-shift``): the learned
    #: adjustment may go beyond ``probes.max_shift_um``.
    accept_shift: bool = False

    def key(self) -> tuple[str, str, float, float, str]:
        """What makes two requests the same probe: axis, source, touch time, value, what it measures."""
        return (self.axis, self.source, self.touched_at_unix_s, self.measured_um, self.measures)


def probe_request(
    message: Mapping[str, Any], now_unix_s: float, measures: Measures, source: str = "socket"
) -> ProbeRequest:
    """A :class:`ProbeRequest` from a control-socket or MQTT message; CompdError says what is wrong."""
    axis = message.get("axis")
    measured = message.get("measured_um")
    touched = message.get("touched_at_unix_s", now_unix_s)
    said = message.get("measures", measures)
    if not isinstance(axis, str):
        raise CompdError('a probe names its axis: {"axis": "Z", "measured_um": 3.2}')
    for name, value in (("measured_um", measured), ("touched_at_unix_s", touched)):
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
        ):
            raise CompdError(
                f"a probe's {name} must be a finite number (um, unix s), not {value!r}"
            )
    if said not in ("residue", "thermal_error"):
        raise CompdError(f"a probe measures 'residue' or 'thermal_error', not {said!r}")
    assert isinstance(measured, int | float) and isinstance(touched, int | float)
    accept_shift = message.get("accept_shift", False)
    if not isinstance(accept_shift, bool):
        raise CompdError(f"a probe's accept_shift is true or false, not {accept_shift!r}")
    if touched > now_unix_s + 60.0:
        raise CompdError(f"the probe's touch time is {touched - now_unix_s:.0f} s in the future")
    source = message.get("source", source)
    return ProbeRequest(
        axis, float(measured), float(touched), str(source)[:64], said, accept_shift=accept_shift
    )


@dataclass(frozen=True)
class ProbeTaken:
    """A probe as the loop took it: the update's steps, or why it was refused."""

    request: ProbeRequest
    model_sha256: str
    output: str
    #: The offset in force at the touch instant (um) and the thermal error it gives (um).
    offset_um: float
    thermal_error_um: float
    steps: tuple[ProbeStep, ...] = ()
    refused: str | None = None
    #: The learners' states after the probe (JSON-able), for the state directory.
    learned: Mapping[str, dict[str, Any]] = field(default_factory=dict)
    #: :data:`DUPLICATE` or :data:`TOO_SOON`: not given to the update (``refused`` says why).
    not_given: str | None = None
    #: For a duplicate: the probe as it was taken the first time.
    original: ProbeTaken | None = None

    @property
    def result(self) -> str:
        """``duplicate``, ``too_soon`` or ``refused``, else the last step's result
        (``accepted``, ``flagged``, ``confirmed``)."""
        if self.not_given is not None:
            return self.not_given
        return "refused" if self.refused is not None else self.steps[-1].result

    def event_details(self) -> dict[str, Any]:
        """What a telemetry event and the status say of it (um, unix s)."""
        if self.original is not None:  # the answer the first time, said to be a resend's
            return self.original.event_details() | {
                "result": self.result,
                "original_result": self.original.result,
                "reason": self.refused,
            }
        step = self.steps[-1] if self.steps else None
        return {
            "axis": self.request.axis,
            "source": self.request.source,
            "result": self.result,
            "touched_at_unix_s": self.request.touched_at_unix_s,
            "measured_um": self.request.measured_um,
            "innovation_um": None if step is None else round(step.innovation_before_um, 4),
            "innovation_after_um": None if step is None else round(step.innovation_after_um, 4),
            "reason": self.refused,
        }


@dataclass(frozen=True)
class ProbeSetup:
    """What the config says of probes: what they measure, when one is due, the update's settings."""

    measures: Measures = "residue"
    every_h: float = 2.0
    overrides: Mapping[str, float] = field(default_factory=dict)
    #: Axes probed (names under ``outputs``).
    axes: tuple[str, ...] = ()
    #: One probe per axis is given to the update per this much touch time (s):
    #: :mod:`compd.service.loop.probegate`.
    min_gap_s: float = 900.0


@dataclass(frozen=True)
class ProbeRegisters:
    """One axis's probe interface on its PLC: read value and counter (and the stamp), write echo and status."""

    axis: str
    driver: str
    value: SignalPoint
    counter: SignalPoint
    echo_address: str
    echo: SignalPoint
    touched_at: SignalPoint | None = None
    status_address: str | None = None

    def reads(self) -> list[SignalPoint]:
        """The points read each tick (the echo too: what compd last took, as the PLC holds it)."""
        return [p for p in (self.value, self.counter, self.echo, self.touched_at) if p is not None]
