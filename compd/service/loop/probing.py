"""Probe measurements in the loop: the running model's parameters updated as probes come in.

A probe arrives from the PLC's probe cycle (a value register and a counter,
:class:`ProbeRegisters`), the control socket (``compd model probe``) or MQTT,
as a :class:`ProbeRequest`: per axis, what was measured and when the probe
touched. Each tick, after the model has stepped, :class:`ProbeLearning`

1. keeps the regressors of every probed output
   (:class:`~compd.model.probelearner.OutputLearner`: the contributions of its
   sub-models, then 1) and the offset in force per axis;
2. takes the probes that arrived: what a probe measures with compensation on
   is the residue, so the thermal error the model should have predicted is the
   residue plus the offset in force at the touch instant
   (:func:`~compd.model.proberegressors.probed_thermal_error_um`, the one place
   the sign is decided); the update, its guard rails and its flagging of a
   probe far from the prediction are :mod:`compd.model.probeupdate`'s;
3. gives each output's learned adjustment, which the compensator adds to the
   model's output before the safety stage: clamp and slew still apply, so an
   update never steps the offset.

A model switched in starts from its own prior, or from what the probes taught
it before (``restore``, from the state directory by the model's sha256); the
learned parameters of the previous model are kept on disk under its own sha.
The probe status per axis: *due* after ``every_h`` hours without a probe
taken; *disagrees* after two probes in a row the update would not take (the
model no longer describes the machine).

Each probe is taken once and within bounds: a resend or one touched within
``min_gap_s`` of the last is answered and not given to the update
(:mod:`compd.service.loop.probegate`); a value beyond what a thermal error
can be is refused; an update that fails (any exception, a number that
overflows) is refused with its reason and taken back, learning stays on, and
the fault shows in the status and ``/healthz`` until an update succeeds.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import structlog

from compd.errors import ModelError
from compd.faultlog import FaultLog
from compd.files.probeprior import output_prior
from compd.model.probelearner import OutputLearner
from compd.model.proberegressors import output_columns, probed_thermal_error_um
from compd.model.probesettings import MAX_PROBE_UM, ProbeSettings, max_probe_um
from compd.model.updateprior import Prior
from compd.service.loop.offsethistory import OFFSET_HISTORY_S, OffsetHistory
from compd.service.loop.offsets import AxisPoint
from compd.service.loop.points import SignalPoint
from compd.service.loop.probegate import ProbeGate
from compd.service.loop.probemessages import ProbeRegisters, ProbeRequest, ProbeSetup, ProbeTaken
from compd.service.loop.slots import ModelSlot

__all__ = ["OFFSET_HISTORY_S", "OffsetHistory", "ProbeLearning"]

log = structlog.get_logger("compd.service.loop.probing")

#: A shift (s): each one ends with a line of the RMS of its probe residues, the shop's evidence.
SHIFT_S = 8 * 3600.0
#: Probe status bits (the probe status register, and ``compd status``).
DUE_BIT, DISAGREES_BIT = 1 << 0, 1 << 1
#: Probes waiting for the next tick, per axis at most (a flood is refused at the door).
MAX_QUEUED = 64
#: The answers kept for the socket and MQTT to find their own (the newest).
ANSWERS_KEPT = 512


class ProbeLearning:
    """The probed outputs' learners of the running model, fed each tick; probes taken as they arrive.

    ``restore(slot, setups, now_unix_s)`` gives the learners the state
    directory keeps for ``slot``'s model (empty: start from the priors).
    """

    def __init__(
        self,
        setup: ProbeSetup,
        axes: Sequence[AxisPoint],
        registers: Sequence[ProbeRegisters] = (),
        *,
        restore: Callable[
            [ModelSlot, Mapping[str, tuple[Prior, ProbeSettings]], float],
            dict[str, OutputLearner],
        ]
        | None = None,
    ) -> None:
        self.setup = setup
        self.axes = {a.name: a for a in axes if a.name in setup.axes}
        self.registers = {r.axis: r for r in registers}
        self.restore = restore
        #: The model whose learners run (sha256), its learners per output, their columns.
        self.sha256: str | None = None
        self.learners: dict[str, OutputLearner] = {}
        self._columns: dict[str, list[int]] = {}
        self._output_index: dict[str, int] = {}
        self.notes: dict[str, str] = {}
        self._queue: deque[ProbeRequest] = deque()
        self._offsets = {axis: OffsetHistory() for axis in self.axes}
        #: Per axis, the last count compd took from the PLC (None until read: the echo register says).
        self.taken_count: dict[str, int | None] = dict.fromkeys(self.registers)
        self.started_s: float | None = None
        #: Per axis: probes by result, the last probe taken, the last innovation (um).
        self.results: dict[str, dict[str, int]] = {axis: {} for axis in self.axes}
        #: Per axis, the probes that reached the loop (a flagged one that a later probe
        #: confirms is counted once here, under both results in ``results``).
        self.probes: dict[str, int] = dict.fromkeys(self.axes, 0)
        self.last: dict[str, ProbeTaken] = {}
        self.adjustments_um: dict[str, float] = {}
        self._taken_now: tuple[ProbeTaken, ...] = ()
        #: Per axis, each probe's innovation (touch unix s, um) over the last shift.
        self.residues: dict[str, deque[tuple[float, float]]] = {axis: deque() for axis in self.axes}
        self._shift = 0
        #: Why probing was turned off (a failure of the learning itself); None while it runs.
        self.off: str | None = None
        self.gate = ProbeGate(setup.min_gap_s)
        #: The last answers (the socket's and MQTT's requests find theirs by identity).
        self.answers: deque[ProbeTaken] = deque(maxlen=ANSWERS_KEPT)
        #: A failure of the update, of a tick's regressors: ERROR once per episode each, and
        #: what failed while the episode lasts (the status and /healthz say it).
        self.failures = {"update": FaultLog(log), "tick": FaultLog(log)}
        self.failing: dict[str, str] = {}

    def reads(self) -> list[SignalPoint]:
        """The probe registers read each tick with the signals."""
        return [point for reg in self.registers.values() for point in reg.reads()]

    # -- intake ----------------------------------------------------------------------------------

    def offer(self, request: ProbeRequest) -> None:
        """Queue a probe (taken at the next tick); an axis not probed or a value not finite is refused."""
        if self.off is not None:
            raise ModelError(f"probes are off until the daemon restarts: {self.off}")
        if request.axis not in self.axes:
            raise ModelError(
                f"axis {request.axis!r} is not probed: name it under probes.axes "
                f"(probed: {sorted(self.axes) or 'none'})"
            )
        if not (math.isfinite(request.measured_um) and math.isfinite(request.touched_at_unix_s)):
            raise ModelError("a probe's value and touch time must be finite numbers")
        why = self._beyond(request)
        if why is None and sum(1 for r in self._queue if r.axis == request.axis) >= MAX_QUEUED:
            why = f"{MAX_QUEUED} probes of {request.axis} are waiting for the next tick: not taken"
        if why is not None:
            self.gate.refused_at_once(request, why)
            raise ModelError(why)
        self._queue.append(request)

    def answer(self, request: ProbeRequest) -> ProbeTaken | None:
        """What the loop did with ``request`` (this very object); None: not yet."""
        return next((a for a in reversed(self.answers) if a.request is request), None)

    def _beyond(self, request: ProbeRequest) -> str | None:
        """Why the value is not a thermal error (beyond 1 mm or 10 calibration peaks); None: it may be."""
        learner = self.learners.get(self.axes[request.axis].model_output)
        bound = MAX_PROBE_UM if learner is None else max_probe_um(learner.prior)
        if abs(request.measured_um) <= bound:
            return None
        return (
            f"a probe of {request.measured_um:g} um is beyond what a thermal error of "
            f"{request.axis} can be ({bound:g} um: 1 mm, or 10 times the calibration's largest "
            "output): check the value and its unit (um); not taken"
        )

    def read_registers(self, values: Mapping[str, float], now_unix_s: float) -> None:
        """Queue each axis's new PLC probe: a count not yet taken (the echo says what compd took last)."""
        for axis, reg in self.registers.items():
            count = values.get(reg.counter.name)
            if count is None or not math.isfinite(count):
                continue
            taken = self.taken_count[axis]
            if taken is None:  # the first read: what compd took before, as the PLC holds it
                echo = values.get(reg.echo.name)
                if echo is None or not math.isfinite(echo):
                    continue
                taken = self.taken_count[axis] = int(echo)
            if int(count) == taken:
                continue
            self.taken_count[axis] = int(count)
            value = values.get(reg.value.name)
            stamp = values.get(reg.touched_at.name) if reg.touched_at is not None else None
            touched = (
                stamp if stamp is not None and math.isfinite(stamp) and stamp > 0 else now_unix_s
            )
            if value is None or not math.isfinite(value):
                log.error("probe value unreadable: count taken, value not", axis=axis, count=count)
                continue
            missed = int(count) - taken - 1
            if missed > 0:
                log.warning(
                    "probes missed: only the PLC's latest value is there", axis=axis, missed=missed
                )
            self._queue.append(
                ProbeRequest(axis, value, touched, "plc", self.setup.measures, int(count))
            )

    def writes(self, now_unix_s: float) -> dict[str, dict[str, float]]:
        """Per driver, the echo (the last count taken) and the probe status word of each axis."""
        batches: dict[str, dict[str, float]] = {}
        for axis, reg in self.registers.items():
            batch = batches.setdefault(reg.driver, {})
            if (count := self.taken_count[axis]) is not None:
                batch[reg.echo_address] = float(count)
            if reg.status_address is not None:
                batch[reg.status_address] = float(self.status_bits(axis, now_unix_s))
        return {d: b for d, b in batches.items() if b}

    # -- each tick -------------------------------------------------------------------------------

    def follow(self, slot: ModelSlot, now_unix_s: float = math.nan) -> None:
        """Run ``slot``'s learners: its own prior, or what the state directory kept for it."""
        if slot.sha256 == self.sha256:
            return
        self.sha256 = slot.sha256
        compiled = slot.compiled
        setups: dict[str, tuple[Prior, ProbeSettings]] = {}
        self._columns, self.notes = {}, {}
        for axis in self.axes.values():
            output = axis.model_output
            if output in setups:
                continue
            columns, names = output_columns(compiled, output)
            prior = output_prior(slot.model_file, output, names)
            settings = ProbeSettings.defaults(
                prior.prior, interval_s=self.setup.every_h * 3600.0, **dict(self.setup.overrides)
            )
            setups[output] = (prior.prior, settings)
            self._columns[output] = [int(c) for c in columns]
            if prior.note:
                self.notes[output] = prior.note
                log.warning("probe update without the calibration's prior", note=prior.note)
        self._output_index = {name: i for i, name in enumerate(compiled.output_names)}
        learners = self.restore(slot, setups, now_unix_s) if self.restore is not None else {}
        self.learners = {
            output: learners.get(output) or OutputLearner(prior, settings)
            for output, (prior, settings) in setups.items()
        }
        if slot.started_cold:
            for output, learner in self.learners.items():
                shift = learner.forget_shift()
                if shift != 0.0:
                    log.info(
                        "cold start: the learned shift is set back, the next probe re-decides it; "
                        "the learned coefficients carry over",
                        model=compiled.name,
                        output=output,
                        shift_um=round(shift, 3),
                    )

    def turn_off(self, why: str) -> None:
        """After a failure of the learning itself: nothing learned is applied, no probe taken, until restart."""
        self.off = why
        self.adjustments_um = dict.fromkeys(self.adjustments_um, 0.0)
        self._taken_now = ()
        self._queue.clear()

    def observe(self, t_unix_s: float, slot: ModelSlot) -> None:
        """Keep this tick's regressors, take the probes that arrived, and work out the adjustments."""
        if self.off is not None:
            self._taken_now = ()
            return
        if self.started_s is None:
            self.started_s = t_unix_s
        shift = int((t_unix_s - self.started_s) // SHIFT_S)
        if shift > self._shift:
            self._shift = shift
            self._say_shift(t_unix_s)
        # Times in the future are clamped where they can come from, a saved state (ProbeKeeper):
        # the loop's clock is the wall's mapped once at start, and a touch may not lie ahead of it.
        self.follow(slot, t_unix_s)
        runner = slot.runner
        self.adjustments_um = dict.fromkeys(self.learners, 0.0)
        self._taken_now = ()
        if runner is None:  # not started: no contributions yet
            return
        # In Python floats: each numpy call costs tens of us in a tick after the loop's sleep.
        contributions = runner.contributions_um
        outputs = slot.outputs
        regressors = {}
        for output, learner in self.learners.items():
            owned = [contributions[c] for c in self._columns[output]]
            x = learner.prior.regressor_row(owned)
            fixed = float(outputs[self._output_index[output]]) - sum(owned)
            if not (all(map(math.isfinite, x)) and math.isfinite(fixed)):
                continue
            try:
                learner.observe(t_unix_s, x, fixed)
            except Exception as exc:  # nothing learned is applied while it fails; learning stays on
                self._failed("tick", "the probe learner cannot keep the ticks", output, exc)
                continue
            regressors[output] = x
        if len(regressors) == len(self.learners):
            self._works("tick", "the probe learner keeps the ticks again")
        self._taken_now = self._take(t_unix_s)
        for output, x in regressors.items():
            self.adjustments_um[output] = self.learners[output].adjustment_um(x)

    def record_offsets(self, t_unix_s: float, offsets_um: Mapping[str, float]) -> None:
        """The offset in force per axis after this tick's write (um)."""
        for axis, history in self._offsets.items():
            offset = offsets_um.get(axis)
            if offset is not None and math.isfinite(offset):
                history.append(t_unix_s, offset)

    def taken(self) -> tuple[ProbeTaken, ...]:
        """The probes taken this tick (after :meth:`observe`): given to the update, or refused by it.

        A resend or a probe too soon is answered (:meth:`answer`) and counted,
        not passed on: a flood must not flood the recorder and telemetry too.
        """
        return tuple(t for t in self._taken_now if t.not_given is None)

    def innovations_um(self) -> dict[str, float]:
        """Per probed axis, this tick's probe innovation (measured minus predicted, um); NaN: none."""
        out = dict.fromkeys(self.axes, math.nan)
        for taken in self._taken_now:
            if taken.steps:
                out[taken.request.axis] = taken.steps[-1].innovation_before_um
        return out

    def _take(self, now_unix_s: float) -> tuple[ProbeTaken, ...]:
        done: list[ProbeTaken] = []
        while self._queue:
            request = self._queue.popleft()
            taken = self._take_one(request)
            self.answers.append(taken)
            if taken.not_given is not None:  # answered, not a probe of the machine
                counts = self.results[request.axis]
                counts[taken.result] = counts.get(taken.result, 0) + 1
                done.append(taken)
                continue
            self.gate.remember(taken)
            self.last[request.axis] = taken
            if taken.steps:
                touched = request.touched_at_unix_s
                self.residues[request.axis].append((touched, taken.steps[-1].innovation_before_um))
            self.probes[request.axis] = self.probes.get(request.axis, 0) + 1
            counts = self.results[request.axis]
            for step in taken.steps or ():
                counts[step.result] = counts.get(step.result, 0) + 1
            if taken.refused is not None:
                counts["refused"] = counts.get("refused", 0) + 1
            done.append(taken)
        return tuple(done)

    def _take_one(self, request: ProbeRequest) -> ProbeTaken:
        axis = self.axes[request.axis]
        output = axis.model_output
        learner = self.learners.get(output)
        assert self.sha256 is not None
        last_touch_s = None if learner is None else learner.updater.last_time_s
        if (answered := self.gate.screen(request, self.sha256, output, last_touch_s)) is not None:
            return answered
        offset = math.nan
        try:
            if learner is None:
                raise ModelError("the model has not started: no regressors yet")
            if (why := self._beyond(request)) is not None:  # the PLC's registers come here only
                raise ModelError(why)
            offset = self._offsets[request.axis].at(request.touched_at_unix_s)
            error = (
                probed_thermal_error_um(request.measured_um, offset, axis.sign)
                if request.measures == "residue"
                else float(request.measured_um)
            )
            steps = learner.probe(
                request.touched_at_unix_s, error, accept_shift=request.accept_shift
            )
        except ModelError as exc:
            log.error(
                "probe refused",
                axis=request.axis,
                source=request.source,
                measured_um=request.measured_um,
                reason=str(exc),
            )
            return ProbeTaken(request, self.sha256, output, offset, math.nan, refused=str(exc))
        except Exception as exc:  # a bug or a number that overflows: this probe only, taken back
            self._failed(
                "update", "probe update failed: probe refused, parameters as before", output, exc
            )
            why = f"the update failed ({type(exc).__name__}: {exc}): the parameters are as before"
            return ProbeTaken(request, self.sha256, output, offset, math.nan, refused=why)
        self._works("update", "probe updates work again")
        taken = ProbeTaken(
            request,
            self.sha256,
            output,
            offset,
            error,
            tuple(steps),
            learned={name: ln.state() for name, ln in self.learners.items()},
        )
        last = steps[-1]
        say = log.warning if last.result == "flagged" else log.info
        say(
            f"probe {last.result}",
            axis=request.axis,
            source=request.source,
            measured_um=round(request.measured_um, 3),
            thermal_error_um=round(error, 3),
            predicted_um=round(last.predicted_um, 3),
            innovation_um=round(last.innovation_before_um, 3),
        )
        return taken

    def _failed(self, kind: str, event: str, output: str, exc: Exception) -> None:
        error = f"{type(exc).__name__}: {exc}"
        self.failing[kind] = f"{event} ({output}: {error})"
        self.failures[kind].failed(event, output=output, error=error)

    def _works(self, kind: str, event: str) -> None:
        self.failing.pop(kind, None)
        self.failures[kind].cleared(event)

    @property
    def fault(self) -> str | None:
        """What fails in the probe learning now (None: nothing)."""
        return "; ".join(self.failing.values()) or None

    # -- status ----------------------------------------------------------------------------------

    def problem(self) -> str | None:
        """What /healthz says of the probe learning: off, or failing now; None: it works."""
        if self.off is not None:
            return f"probe learning is off until the daemon restarts: {self.off}"
        if (fault := self.fault) is not None:
            return f"probe learning fails: {fault}"
        return None

    def shift_rms_um(self, axis: str, now_unix_s: float) -> tuple[float | None, int]:
        """The RMS of the axis's probe residues over the last shift (um; None without one), and their count."""
        kept = self.residues[axis]
        while kept and kept[0][0] < now_unix_s - SHIFT_S:
            kept.popleft()
        if not kept:
            return None, 0
        return math.sqrt(sum(e * e for _, e in kept) / len(kept)), len(kept)

    def _say_shift(self, now_unix_s: float) -> None:
        """One line a shift per axis: how well compensation held on the parts, from its probes."""
        for axis in self.axes:
            rms, count = self.shift_rms_um(axis, now_unix_s)
            log.info(
                "probe residues this shift",
                axis=axis,
                rms_um=None if rms is None else round(rms, 3),
                probes=count,
                shift_h=SHIFT_S / 3600,
            )

    def adjustment(self, output: str) -> float:
        """What the probes add to ``output`` this tick (um); 0 before any probe taken."""
        return self.adjustments_um.get(output, 0.0)

    def last_taken_s(self, axis: str) -> float | None:
        learner = self.learners.get(self.axes[axis].model_output)
        return None if learner is None else learner.last_taken_s

    def due(self, axis: str, now_unix_s: float) -> bool:
        """A probe is due: ``every_h`` since the last probe taken (or since the start, without one)."""
        since = self.last_taken_s(axis)
        if since is None:
            since = self.started_s if self.started_s is not None else now_unix_s
        return now_unix_s - since >= self.setup.every_h * 3600.0

    def disagrees(self, axis: str) -> bool:
        """Two probes in a row the update would not take: the model no longer describes the machine."""
        learner = self.learners.get(self.axes[axis].model_output)
        return learner is not None and learner.untaken_in_a_row >= 2

    def status_bits(self, axis: str, now_unix_s: float) -> int:
        return (DUE_BIT if self.due(axis, now_unix_s) else 0) | (
            DISAGREES_BIT if self.disagrees(axis) else 0
        )

    def reset(self) -> None:
        """Back to the calibration's parameters (every output's prior)."""
        for learner in self.learners.values():
            learner.reset()
        self.adjustments_um = dict.fromkeys(self.learners, 0.0)
        self.gate.forget()

    def status(self, now_unix_s: float) -> dict[str, Any]:
        """Per axis: due, disagrees, the last probe, counts by result, the adjustment now."""
        axes = {}
        for name, axis in self.axes.items():
            last = self.last.get(name)
            taken_s = self.last_taken_s(name)
            shift_rms, shift_probes = self.shift_rms_um(name, now_unix_s)
            axes[name] = {
                "output": axis.model_output,
                "due": self.due(name, now_unix_s),
                "disagrees": self.disagrees(name),
                "adjustment_um": round(self.adjustment(axis.model_output), 4),
                "last_taken_age_s": None if taken_s is None else round(now_unix_s - taken_s, 1),
                "last": None if last is None else last.event_details(),
                "probes": self.probes[name],
                #: The RMS of the probe residues of the last shift (8 h), and how many.
                "shift_rms_um": _rounded(shift_rms),
                "shift_probes": shift_probes,
                "results": dict(self.results[name]),
            }
        return {
            "model_sha256": self.sha256,
            "every_h": self.setup.every_h,
            "min_gap_s": self.setup.min_gap_s,
            "off": self.off,
            "fault": self.fault,
            "axes": axes,
        }


def _rounded(value: float | None) -> float | None:
    return None if value is None else round(value, 4)
