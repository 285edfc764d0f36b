"""The ``simulation:`` section's schema: the simulated machine a config runs against.

Checked where every other section is (the loader: a misspelt key, a fault
without its signal, an hour count out of bounds are errors naming the key and
the fix) and documented where every other section is (``compd help config``:
each key with its unit). The service never runs the machine: ``compd run``
and ``compd simulate-machine`` start it (:mod:`compd.sim.plc.build`, which also
checks the names against the twin: its scenarios, variants and quantities).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from compd.service.config.docbase import Strict

#: What a fault does (``SimFaultDoc``): to a sensor (a signal) or to a controller (a driver).
FaultKind = Literal["stuck", "nan", "value", "offset", "drift", "drop", "restart"]
TwinAxis = Literal["x", "y", "z"]
Seconds = Annotated[float, Field(ge=0, allow_inf_nan=False)]

_KINDS = (
    "stuck: the sensor holds its reading at at_s; nan: it reads NaN (an integer point its "
    "type's minimum, a wire-break code); value: it reads 'value'; offset: it reads 'value' "
    "off the truth; drift: it departs at 'rate_per_h'; drop: the controller is unreachable; "
    "restart: the controller restarts at at_s"
)


class SimFaultDoc(Strict):
    """A fault injected at ``at_s`` (simulated s from the start), lasting ``duration_s``.

    - ``stuck`` / ``nan`` / ``value``: the sensor behind ``signal`` reads its value at
      ``at_s`` / NaN (a float point; an integer point reads its type's minimum, a
      wire-break code) / ``value`` (in the signal's unit, e.g. out of range);
    - ``offset``: the sensor behind ``signal`` reads ``value`` (its unit) off the truth: a
      plausible wrong value that follows the signal (a bad contact, a wrong linearisation);
    - ``drift``: the sensor behind ``signal`` departs from the truth at ``rate_per_h`` (its unit
      per hour) from ``at_s``, ``rate_per_h * (t - at_s) / 3600`` off, for ``duration_s`` (an
      ageing sensor, a creeping contact resistance); then it reads true again;
    - ``drop``: the controller behind ``driver`` is unreachable for ``duration_s``;
    - ``restart``: the controller behind ``driver`` restarts (connections drop) at ``at_s``.
    """

    kind: FaultKind = Field(description=_KINDS)
    at_s: Seconds = Field(description="when it starts: simulated s from the scenario's start")
    duration_s: Seconds = Field(
        default=0.0, description="how long it lasts, s (above 0 for every kind but restart)"
    )
    signal: str | None = Field(
        default=None, description="the config signal a sensor fault hits (not drop/restart)"
    )
    driver: str | None = Field(default=None, description="the config driver a drop or restart hits")
    value: float | None = Field(
        default=None,
        description="value: the reading; offset: how far off the truth (the signal's unit)",
    )
    rate_per_h: Annotated[float, Field(allow_inf_nan=False)] | None = Field(
        default=None, description="drift only: the signal's unit per hour"
    )

    @model_validator(mode="after")
    def _target(self) -> SimFaultDoc:
        on_driver = self.kind in ("drop", "restart")
        if on_driver and not self.driver:
            raise ValueError(f"a {self.kind!r} fault needs 'driver': the controller it hits")
        if not on_driver and not self.signal:
            raise ValueError(f"a {self.kind!r} fault needs 'signal': the sensor it hits")
        if self.kind in ("value", "offset") and self.value is None:
            raise ValueError(f"a {self.kind!r} fault needs 'value', in the signal's unit")
        if (self.kind == "drift") != (self.rate_per_h is not None):
            raise ValueError(
                "a 'drift' fault needs 'rate_per_h' (the signal's unit per hour), and only a "
                f"'drift' takes it (this one is {self.kind!r})"
            )
        if self.kind != "restart" and not self.duration_s > 0:
            raise ValueError(f"a {self.kind!r} fault needs 'duration_s' above 0")
        return self


class SimMisprobeDoc(Strict):
    """A mis-probe (a chip on the datum ball): the first cycle touching at or after ``at_s`` is ``error_um`` off.

    ``axis`` (an output under ``probes.axes``) limits it to that axis's probe;
    without, the next cycle of every probed axis is spoilt.
    """

    at_s: Seconds = Field(description="simulated s from the start")
    error_um: Annotated[float, Field(allow_inf_nan=False)] = Field(
        description="how far off that touch reads, um"
    )
    axis: str | None = Field(default=None, description="one probed axis (default: every one)")


class SimProbesDoc(Strict):
    """``simulation.probes``: when the simulated PLC runs its probe cycles, and what they read.

    A cycle probes one axis through its registers under ``probes.axes``: it
    touches at its start, and ``cycle_s`` later writes the value (the axis's
    compensated error at the touch, ``true thermal error + applied offset``
    um, or the true thermal error alone where ``probes.measures`` is
    ``thermal_error``, plus Gaussian noise of ``noise_um`` and any mis-probe),
    the touch's unix time, then increments the counter. At most one cycle per
    axis is under way. Cycles start

    - on a timer, at ``every_h``, 2 ``every_h``, ... hours of machine time (null: no
      timer; one due while a cycle is under way starts when that one ends);
    - with ``when_due``, when compd's probe status word (``probes.axes.<axis>.status_address``)
      has bit 0 "probe due" set, and no cycle touched within ``min_gap_h``.

    Neither set (the default): the PLC never probes. The noise is drawn from
    ``simulation.seed``, so a run on virtual time is repeatable.
    """

    every_h: Annotated[float, Field(gt=0, le=24 * 14, allow_inf_nan=False)] | None = Field(
        default=None, description="a cycle on the PLC's own timer every this many h (null: none)"
    )
    when_due: bool = Field(
        default=False, description="a cycle when compd's probe status word says due (bit 0)"
    )
    min_gap_h: Annotated[float, Field(ge=0, le=24 * 14, allow_inf_nan=False)] = Field(
        default=0.25, description="with when_due: no cycle within this many h of the last touch"
    )
    cycle_s: Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False)] = Field(
        default=60.0, description="from the touch to the value written, s"
    )
    noise_um: Annotated[float, Field(ge=0, le=1000, allow_inf_nan=False)] = Field(
        default=0.5, description="the probe's Gaussian noise, um (standard deviation)"
    )
    misprobes: tuple[SimMisprobeDoc, ...] = Field(
        default=(), description="touches spoilt on purpose: [{at_s, error_um, axis}]"
    )

    @property
    def runs(self) -> bool:
        """Whether any cycle can start: a timer, or answers to compd's probe-due bit."""
        return self.every_h is not None or self.when_due


class SimulationDoc(Strict):
    """The simulated machine (compd run starts it): which run of the twin, how the config's names map onto it."""

    scenario: str = Field(
        default="production", description="the twin's run: 'compd twin --help' lists them"
    )
    hours: Annotated[float, Field(gt=0, le=24 * 14, allow_inf_nan=False)] = Field(
        default=8.0, description="the scenario's length, h of machine time"
    )
    seed: int = Field(default=0, ge=0, description="the random draws (repeatable runs)")
    variant: str = Field(
        default="reference",
        description="the machine's build: reference, spindle-head or long-nose "
        "('compd twin --help')",
    )
    sample_time_s: Annotated[float, Field(gt=0, le=10, allow_inf_nan=False)] = Field(
        default=1.0, description="the twin's step, s"
    )
    signals: dict[str, str] = Field(
        default_factory=dict,
        description="config signal -> twin quantity (default: the same name)",
    )
    axes: dict[str, TwinAxis] = Field(
        default_factory=dict,
        description="config output -> twin axis (default: from its model output, disp_<axis>_um)",
    )
    heartbeat_timeout_s: Annotated[float, Field(gt=0, allow_inf_nan=False)] = Field(
        default=5.0, description="the PLC counts a heartbeat not renewed this long, s"
    )
    faults: tuple[SimFaultDoc, ...] = Field(
        default=(), description="faults injected on the simulated clock"
    )
    probes: SimProbesDoc = Field(
        default=SimProbesDoc(), description="the PLC's probe cycles (default: none run)"
    )
    stop_at_end: bool = Field(
        default=True,
        description="compd run stops at the scenario's end (unless --duration-s says otherwise)",
    )
    join_at_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = Field(
        default=0.0,
        description="compd joins the machine this far in, simulated s (uncompensated till then: "
        "a machine already warm); the summary covers the rest",
    )
