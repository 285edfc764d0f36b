"""The ``simulation:`` section of a compd config: the simulated machine the config runs against.

With it, ``compd run`` starts the machine in the same process before the
service, and ``compd simulate-machine`` starts the machine alone. The rest of
the config is unchanged: the drivers connect to the simulated controllers as
they would to a real machine (a ``type: modbus`` driver to a simulated Modbus
TCP server at its host and port, and so on).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from compd.errors import ConfigFileError
from compd.service.config.loading import Config, validation_error

FaultKind = Literal["stuck", "nan", "value", "offset", "drift", "drop", "restart"]
TwinAxis = Literal["x", "y", "z"]
Seconds = Annotated[float, Field(ge=0, allow_inf_nan=False)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SimFaultDoc(_Strict):
    """A fault at ``at_s`` (simulated seconds from the start) lasting ``duration_s``.

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

    kind: FaultKind
    at_s: Seconds
    duration_s: Seconds = 0.0
    signal: str | None = None
    driver: str | None = None
    value: float | None = None
    #: A ``drift``'s rate, in the signal's unit per hour.
    rate_per_h: Annotated[float, Field(allow_inf_nan=False)] | None = None

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


class SimMisprobeDoc(_Strict):
    """A mis-probe (a chip on the datum ball): the first cycle touching at or after ``at_s`` is ``error_um`` off.

    ``axis`` (an output under ``probes.axes``) limits it to that axis's probe;
    without, the next cycle of every probed axis is spoilt.
    """

    at_s: Seconds
    error_um: Annotated[float, Field(allow_inf_nan=False)]
    axis: str | None = None


class SimProbesDoc(_Strict):
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

    every_h: Annotated[float, Field(gt=0, le=24 * 14, allow_inf_nan=False)] | None = None
    when_due: bool = False
    min_gap_h: Annotated[float, Field(ge=0, le=24 * 14, allow_inf_nan=False)] = 0.25
    cycle_s: Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False)] = 60.0
    noise_um: Annotated[float, Field(ge=0, le=1000, allow_inf_nan=False)] = 0.5
    misprobes: tuple[SimMisprobeDoc, ...] = ()

    @property
    def runs(self) -> bool:
        """Whether any cycle can start: a timer, or answers to compd's probe-due bit."""
        return self.every_h is not None or self.when_due


class SimulationDoc(_Strict):
    """The simulated machine: which run of the twin, and how the config's names map onto it."""

    scenario: str = Field(default="production", description="a twin scenario (compd twin --list)")
    hours: Annotated[float, Field(gt=0, le=24 * 14, allow_inf_nan=False)] = 8.0
    seed: int = Field(default=0, ge=0)
    variant: str = Field(default="reference", description="a twin machine variant")
    sample_time_s: Annotated[float, Field(gt=0, le=10, allow_inf_nan=False)] = 1.0
    #: Config signal -> twin data column (default: the same name).
    signals: dict[str, str] = Field(default_factory=dict)
    #: Config output axis -> twin axis (default: from the model output, disp_<axis>_um).
    axes: dict[str, TwinAxis] = Field(default_factory=dict)
    #: The PLC's supervision: no new heartbeat for this long counts a heartbeat timeout.
    heartbeat_timeout_s: Annotated[float, Field(gt=0, allow_inf_nan=False)] = 5.0
    faults: tuple[SimFaultDoc, ...] = ()
    #: The PLC's probe cycles through the registers of ``probes.axes`` (default: none run).
    probes: SimProbesDoc = SimProbesDoc()
    #: ``compd run`` stops at the end of the scenario (unless --duration-s says otherwise).
    stop_at_end: bool = True
    #: ``compd run`` joins the machine this far into the scenario (simulated s): until then
    #: the machine runs uncompensated, as where compd is installed on (or restarted beside)
    #: a machine that is already warm; the summary covers the rest of the scenario.
    join_at_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0


def simulation_of(config: Config) -> SimulationDoc:
    """The config's ``simulation:`` section, validated; ConfigFileError names what does not fit."""
    if config.simulation is None:
        raise ConfigFileError(
            config.path,
            "this config has no 'simulation' section",
            where="simulation",
            fix="Add one (see config/simulated.yaml) or run compd against a real machine",
        )
    try:
        return SimulationDoc.model_validate(config.simulation)
    except ValidationError as exc:
        raise validation_error(exc, config.path, config.root, ("simulation",)) from exc
