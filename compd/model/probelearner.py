"""One output's probe learning as the daemon runs it: regressors kept each tick, a probe taken at its touch instant.

An output is ``y = f + x' theta`` (:mod:`compd.model.probeupdate`): ``x`` the
contributions of its sub-models at the file's gains, then 1; ``f`` what no
gain scales. :class:`OutputLearner` wraps the update for the loop:

- :meth:`OutputLearner.observe` every tick, O(p): the regressor is kept,
  one row per ``row_every_s`` bin over the last ``keep_s`` (a probe cycle
  takes a minute, a typed gauge result longer: the value refers to when
  the probe touched, so the regressor of that instant is interpolated
  between the kept rows);
- :meth:`OutputLearner.probe` when a probe arrives: the update at the touch
  instant, the departure bound held over the rows since the last probe
  taken (at most :data:`RECENT_ROWS` of them, evenly spaced);
- :meth:`OutputLearner.adjustment_um` every tick: ``x' (theta - theta0)``,
  what the loop adds to the file model's output: the gains' part on their
  rails, and the bias, which an update may not take beyond ``max_shift_um``
  (:class:`ShiftRefused`) unless a person accepts the shift;
- :meth:`OutputLearner.state` / :meth:`OutputLearner.restore`: the
  parameters, covariance and times as plain JSON values, checked on the way
  back, bounds included (a state is input like any other). The kept
  regressors are not part of the state: after a restart a touch from before
  it is refused (its regressor is not known).

Times are seconds on one axis that survives a restart and only increases
within a run (in the daemon: unix seconds, the loop's time mapped to the
wall clock once at start, as ``Compensator.wall_at`` does): the state
carries the last probe's time, and probes come in time order.

What a probe is regressed on (an output's columns, the kept rows, the probed
output) is :mod:`compd.model.proberegressors`. numpy only: no files, no logging.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from compd.errors import ModelError
from compd.model.learnerstate import restore_into, state_of
from compd.model.probebank import UpdaterBank
from compd.model.probebounds import (
    RESTORE_SKEW_S,
    SIMULATED_SKEW_S,
)
from compd.model.proberegressors import KeptRows, RegressorWindow
from compd.model.probesettings import ProbeSettings
from compd.model.probeupdate import ProbeStep

__all__ = [
    "RESTORE_SKEW_S",
    "SIMULATED_SKEW_S",
    "OutputLearner",
    "ShiftRefused",
]
from compd.model.updateprior import Prior

#: The regressors since the last probe the departure bound is held over, at most this many.
RECENT_ROWS = 240
#: A touch up to this far after the last tick observed takes that tick's regressor (the clocks
#: of a PLC and the daemon, or a person typing "now", differ by a tick or two).
AHEAD_SLACK_S = 5.0


class ShiftRefused(ModelError):
    """An update that would take the learned bias beyond ``max_shift_um``: not applied."""


class OutputLearner:
    """One output's probe update, fed every tick: see the module docstring.

    ``prior`` and ``settings`` as :class:`~compd.model.probeupdate.ProbeUpdater`
    takes them; ``window``: how the regressors are kept (the daemon's
    default: one row a minute over 12 h; ``compd compare --probe-every``
    keeps every sample of the record). Per tick, with ``columns`` from
    :func:`output_columns` and the runner's ``contributions`` (gains
    applied)::

        x = np.append(contributions[columns], 1.0)
        learner.observe(t_s, x, output_um - x[:-1].sum())
        output_um += learner.adjustment_um(x)      # then sign, clamp and slew
    """

    def __init__(
        self, prior: Prior, settings: ProbeSettings, window: RegressorWindow | None = None
    ) -> None:
        self.window = window or RegressorWindow()
        self.updater = UpdaterBank(prior, settings)
        p = len(prior.names)
        self._rows = KeptRows(p, self.window.keep_s)
        self._bin = -math.inf  # the row bin of the last kept row
        #: The last tick: its time, regressor (Python floats: the tick enters no numpy) and
        #: unscaled part.
        self._latest: tuple[float, list[float], float] | None = None
        #: The touch instant of the last probe taken (the departure bound holds over the rows after it).
        self.since_s = -math.inf
        #: Probes in a row the update did not take (flagged, then not confirmed): at 2 the
        #: model no longer describes the machine (issue 35 item 3's status bit).
        self.untaken_in_a_row = 0
        #: The largest |learned bias| a person accepted (um; ``accept_shift``): held as the
        #: bound instead of ``max_shift_um`` where larger, until a reset.
        self.accepted_shift_um = 0.0
        self._set_delta(np.zeros(p))
        #: How far a restored state's latest time lay ahead of the clock, clamped (s; 0: none).
        self.clamped_s = 0.0

    @property
    def prior(self) -> Prior:
        return self.updater.prior

    @property
    def settings(self) -> ProbeSettings:
        return self.updater.settings

    @property
    def theta(self) -> np.ndarray:
        """The parameters: each sub-model's gain on its file contribution, then the bias (um)."""
        return self.updater.theta

    @property
    def last_taken_s(self) -> float | None:
        """When the last probe the update took touched (None: none since the prior): "probe due" counts from it."""
        return None if math.isinf(self.since_s) else self.since_s

    @property
    def updated(self) -> bool:
        """Whether the parameters differ from the prior's (a probe was taken since the last reset)."""
        return bool(np.any(self._delta != 0.0))

    def observe(self, t_s: float, x: Sequence[float] | np.ndarray, fixed_um: float = 0.0) -> None:
        """One tick's regressor ``x`` (p,: contributions, then 1) and unscaled part ``fixed_um``; O(p).

        In Python floats: a tick after the loop's sleep pays tens of us per
        numpy call (cold caches); a row is kept as an array once a minute.
        """
        row = x.tolist() if isinstance(x, np.ndarray) and x.ndim == 1 else x
        if (
            not isinstance(row, list | tuple)
            or len(row) != len(self._delta_row)
            or not all(isinstance(v, float | int) and math.isfinite(v) for v in row)
            or not math.isfinite(fixed_um)
        ):
            raise ModelError(
                f"a regressor needs {len(self._delta_row)} finite values and a finite unscaled "
                f"part; got {np.shape(x)} values at {t_s} s"
            )
        if self._latest is not None and not t_s > self._latest[0]:
            raise ModelError(f"ticks must come in time order: {t_s} s after {self._latest[0]} s")
        self._latest = (float(t_s), [float(v) for v in row], float(fixed_um))
        every = self.window.row_every_s
        row_bin = math.floor(t_s / every) if every > 0.0 else t_s
        if row_bin != self._bin:
            self._bin = row_bin
            self._rows.append(np.array([t_s]), np.array([row], dtype=float), np.array([fixed_um]))

    def observe_many(self, t_s: np.ndarray, x: np.ndarray, fixed_um: np.ndarray) -> None:
        """:meth:`observe` for a record's rows at once (N,), (N, p), (N,): what ``compare`` replays."""
        t_s = np.asarray(t_s, dtype=float)
        x = np.asarray(x, dtype=float)
        fixed_um = np.asarray(fixed_um, dtype=float)
        if not len(t_s):
            return
        if x.shape != (len(t_s), len(self._delta_row)) or fixed_um.shape != t_s.shape:
            raise ModelError(
                f"regressors must be ({len(t_s)}, {len(self._delta_row)}) with {len(t_s)} unscaled "
                f"values; got {x.shape} and {fixed_um.shape}"
            )
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(fixed_um))):
            raise ModelError("regressors and unscaled parts must be finite")
        after = -math.inf if self._latest is None else self._latest[0]
        if not (t_s[0] > after and np.all(np.diff(t_s) > 0.0)):
            raise ModelError("ticks must come in time order")
        every = self.window.row_every_s
        bins = np.floor(t_s / every) if every > 0.0 else t_s
        keep = np.flatnonzero(np.diff(bins, prepend=self._bin) != 0.0)
        if keep.size:
            self._rows.append(t_s[keep], x[keep], fixed_um[keep])
            self._bin = float(bins[-1])
        self._latest = (float(t_s[-1]), x[-1].tolist(), float(fixed_um[-1]))

    def probe(
        self, touched_at_s: float, thermal_error_um: float, *, accept_shift: bool = False
    ) -> list[ProbeStep]:
        """Take a probe: the thermal error (um, :func:`probed_thermal_error_um`) when it touched.

        The regressor at ``touched_at_s`` is interpolated between the kept
        rows; a touch before the oldest kept row (or more than
        :data:`AHEAD_SLACK_S` after the last tick) is refused with a
        :class:`ModelError`. Returns the update's steps (one, or two when it
        confirms a flagged probe), as :meth:`ProbeUpdater.probe` does.

        The learned adjustment ``x' (theta - theta0)`` is the gains' part,
        which their rails hold to a share of each contribution (a machine
        that drifts 1.7 times what it was calibrated for is learned through
        them), and the bias, a shift in um that nothing scales: the bias is
        held within ``settings.max_shift_um`` (or, where it was beyond
        already, may not grow). An update that breaks it is taken back and
        :class:`ShiftRefused` raised, unless ``accept_shift`` (a person says
        the machine moved). Any exception leaves the learner as it was.
        """
        x, fixed_um = self.regressor_at(touched_at_s)
        times, rows, _ = self._rows.view()
        recent = rows[(times > self.since_s) & (times <= touched_at_s)]
        recent = recent[:: max(1, len(recent) // RECENT_ROWS)]
        u = self.updater
        before = u.snapshot()
        steps = u.probe(
            touched_at_s, x, thermal_error_um, fixed_um, recent=recent, accept_shift=accept_shift
        )
        shift = abs(float(u.theta[-1] - self.prior.mean[-1]))
        held = max(self.settings.max_shift_um, self.accepted_shift_um, abs(float(self._delta[-1])))
        if accept_shift:
            self.accepted_shift_um = max(self.accepted_shift_um, shift)
        elif shift > held * (1 + 1e-9):
            u.put_back(before)
            raise ShiftRefused(
                f"the update would move the learned shift (the bias) to {shift:.1f} um, beyond "
                f"the {held:.1f} um the probes may reach alone (probes.max_shift_um): not applied. "
                "If the machine did move (a crash, a re-clamped fixture), a person accepts it: "
                "compd model probe --accept-shift AXIS VALUE"
            )
        if any(step.result in ("accepted", "confirmed") for step in steps):
            self.since_s = touched_at_s
            self.untaken_in_a_row = 0
        else:
            self.untaken_in_a_row += 1
        self._set_delta(self.updater.theta - self.prior.mean)
        return steps

    def regressor_at(self, t_s: float) -> tuple[np.ndarray, float]:
        """The regressor and unscaled part (um) at ``t_s``, linear between the kept rows."""
        if self._latest is None:
            raise ModelError(
                f"a probe at {t_s:g} s cannot be taken: no tick has been observed yet "
                "(its regressor is not known)"
            )
        times, rows, fixed = self._rows.view()
        latest_t, latest_row, latest_f = self._latest
        latest_x = np.array(latest_row)
        if t_s >= latest_t:
            if t_s - latest_t > AHEAD_SLACK_S:
                raise ModelError(
                    f"a probe touched at {t_s:.1f} s, {t_s - latest_t:.1f} s after the last tick "
                    f"observed ({latest_t:.1f} s): give the touch instant on the daemon's time "
                    "axis, and observe the tick first"
                )
            return latest_x, latest_f
        oldest = float(times[0])
        if t_s < oldest:
            raise ModelError(
                f"a probe touched at {t_s:.1f} s is older than the regressors kept (from "
                f"{oldest:.1f} s, {self.window.keep_s / 3600:g} h or since the start): its "
                "regressor is not known, so it cannot be taken; probe again"
            )
        j = int(np.searchsorted(times, t_s, side="right")) - 1
        if j + 1 < len(times):
            t1, x1, f1 = float(times[j + 1]), rows[j + 1], float(fixed[j + 1])
        else:  # between the last kept row and the last tick
            t1, x1, f1 = latest_t, latest_x, latest_f
        t0 = float(times[j])
        if t_s == t0 or t1 == t0:
            return rows[j].copy(), float(fixed[j])
        # np.interp's arithmetic (slope, then from the left point), so the offline judge is exact.
        x = (x1 - rows[j]) / (t1 - t0) * (t_s - t0) + rows[j]
        f = (f1 - float(fixed[j])) / (t1 - t0) * (t_s - t0) + float(fixed[j])
        return x, f

    def adjustment_um(self, x: Sequence[float] | np.ndarray) -> float:
        """``x' (theta - theta0)`` (um): what the loop adds to the file model's output; O(p),
        in Python floats for a tick's list.

        0.0 before any accepted probe (and after :meth:`reset`).
        """
        if isinstance(x, np.ndarray):
            return float(x @ self._delta)
        return float(sum(map(operator.mul, x, self._delta_row)))

    def _set_delta(self, delta: np.ndarray) -> None:
        """``theta - theta0``, and as Python floats for the tick (:meth:`adjustment_um`)."""
        self._delta = delta
        self._delta_row = delta.tolist()

    def adjustments_um(self, rows: np.ndarray) -> np.ndarray:
        """:meth:`adjustment_um` for many regressors (N, p): what ``compare`` adds over a record."""
        adjusted: np.ndarray = np.asarray(rows) @ self._delta
        return adjusted

    def predict(self, x: np.ndarray, fixed_um: np.ndarray | float = 0.0) -> np.ndarray:
        """``f + x' theta`` (um) for one regressor (p,) or many (N, p)."""
        return self.updater.predict(x, fixed_um)

    def reset(self) -> None:
        """Back to the prior: the calibration's parameters (the kept regressors stay)."""
        self.updater = UpdaterBank(self.prior, self.settings)
        self.since_s = -math.inf
        self.untaken_in_a_row = 0
        self.accepted_shift_um = 0.0
        self._set_delta(np.zeros_like(self._delta))

    def state(self) -> dict[str, Any]:
        """The update's state as plain JSON values (no NaN: times not yet set are null)."""
        return state_of(self)

    @classmethod
    def restore(
        cls,
        prior: Prior,
        settings: ProbeSettings,
        state: Mapping[str, Any],
        window: RegressorWindow | None = None,
        *,
        now_s: float | None = None,
        skew_s: float = RESTORE_SKEW_S,
    ) -> OutputLearner:
        """A learner at ``state`` (from :meth:`state`); a :class:`ModelError` names what is wrong.

        Beyond shapes and finite numbers, the bounds an update keeps: gains
        within ``settings.gain_bounds``, the bias within twice the larger of
        ``max_shift_um`` and the shift a person accepted (itself within the
        probe bound, :func:`max_probe_um`), a symmetric positive-definite covariance
        no wider than :data:`MAX_VARIANCE_GROWTH` times the prior's (the bias:
        the probe bound squared more), and, given ``now_s``, no time more than
        ``skew_s`` after it (a simulation's clock runs ahead of the wall: a larger one).
        """
        learner = cls(prior, settings, window)
        restore_into(learner, state, now_s=now_s, skew_s=skew_s)
        learner._set_delta(learner.updater.theta - prior.mean)
        return learner

    def clamp_times(self, now_s: float) -> float:
        """Times after ``now_s`` (a clock set back, a simulation's clock ahead of the wall) set to it.

        Probe due-ness counts from the last probe taken, and probes must come
        after the last one: a time in the future would hold both until the
        clock caught up, a whole shift perhaps. Returns how far the latest
        was ahead (s; 0: none was).
        """
        u = self.updater
        ahead = 0.0
        for updater in (u, *u.members):
            for key in ("last_time_s", "drifted_to_s"):
                t_s = getattr(updater, key)
                if t_s is not None and t_s > now_s:
                    ahead = max(ahead, t_s - now_s)
                    setattr(updater, key, now_s)
        if u.pending is not None and u.pending.time_s > now_s:
            ahead = max(ahead, u.pending.time_s - now_s)
            u.pending.time_s = now_s
        if self.since_s > now_s:
            ahead = max(ahead, self.since_s - now_s)
            self.since_s = now_s
        return ahead

    def forget_shift(self) -> float:
        """The learned bias back to the prior's, with its variance; the gains (coefficients) kept.

        What the probes learned as a constant belongs to the thermal state it
        was learned in: after a cold start the calibrated model's zero holds
        again, and the next probe re-decides the shift (issue 42). Returns
        the shift forgotten (um).
        """
        u = self.updater
        shift = float(u.theta[-1] - self.prior.mean[-1])
        for member in u.members:
            member.theta[-1] = member.prior.mean[-1]
            covariance = member.covariance
            covariance[-1, :] = 0.0
            covariance[:, -1] = 0.0
            covariance[-1, -1] = member.prior.covariance[-1, -1]
            member.covariance = covariance
        u.pending = None
        u.mix()
        self._set_delta(u.theta - self.prior.mean)
        return shift
