"""Guard rails: findings that mark a model as implausible for the data it was fitted on.

A model can fit its calibration record to 99 % and still be nonsense: a
sub-model of -1.1e5 um/K whose eight-year time constant makes it an
integrator over the record, held in check by another of the opposite sign.
Such a model fails on the next run, and a shop that loads it triples its
drift. Each rule here names the sub-model and the fix:

- *gain*: an input's static gain (summed over its sub-models of the same
  structure) times the input's calibration range, against the output's
  range: beyond :data:`GAIN_ERROR_RATIO` times it is an error, beyond
  :data:`GAIN_WARNING_RATIO` a warning;
- *time constant*: longer than the record is a warning (the data cannot pin
  it down), longer than :data:`INTEGRATOR_RECORDS` records an error (the
  sub-model is an integrator over the record);
- *cancelling pair*: two sub-models whose contributions over the record are
  each larger than the output yet sum to much less (needs the contributions);
- *self gate*: a phase gate on the sub-model's own input (``u * (u > 0)`` is
  ``u`` while it runs: the heating and cooling sub-models are the same
  regressor and cancel).

Pure numerics: the caller gives the ranges, the record length and, if it has
them, the contributions.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from compd.errors import ModelError
from compd.model.structure import Model, SubModel
from compd.model.transfer import ContinuousTF, DiscreteTF

GAIN_WARNING_RATIO = 3.0
GAIN_ERROR_RATIO = 10.0
INTEGRATOR_RECORDS = 10.0
#: A pair cancels when each contribution's RMS exceeds this many output RMS ...
CANCEL_SIZE_RATIO = 3.0
#: ... and their sum's RMS is below this fraction of the larger one.
CANCEL_SUM_FRACTION = 0.2


class Severity(StrEnum):
    WARNING = "warning"
    ERROR = "error"


@dataclass(frozen=True)
class Finding:
    """One guard-rail finding: how bad, on which output and sub-model(s), what is wrong, what to do."""

    severity: Severity
    output: str
    submodel: str
    message: str
    fix: str

    def describe(self) -> str:
        return f"{self.severity}: {self.output}/{self.submodel}: {self.message}. {self.fix}"


def time_constants_s(tf: DiscreteTF | ContinuousTF, sample_time_s: float) -> np.ndarray:
    """The TF's time constants in seconds (from its poles)."""
    if isinstance(tf, DiscreteTF):
        return tf.time_constants_s(sample_time_s)
    poles = tf.poles()
    poles = poles[poles.real < 0.0]
    return np.sort(-1.0 / poles.real)[::-1] if poles.size else np.zeros(0)


def _static_gain(sub: SubModel) -> float | None:
    try:
        return sub.gain * sub.tf.static_gain()
    except (
        ModelError
    ):  # a continuous integrator has no static gain; the time-constant rule names it
        return None


def _group(sub: SubModel) -> tuple[object, ...]:
    """Sub-models that differ only in their TF (a lag bank's lags of one input) act as one."""
    return (sub.input, sub.gate, sub.position)


def check_model(
    model: Model,
    *,
    ranges: Mapping[str, tuple[float, float]] | None = None,
    record_s: float | None = None,
    contributions: Mapping[str, Mapping[str, np.ndarray]] | None = None,
) -> list[Finding]:
    """All findings for ``model`` given the calibration ``ranges`` ([min, max] per signal), its length (s)
    and, optionally, each sub-model's contribution over the record (``{output: {sub-model: um}}``)."""
    findings: list[Finding] = []
    for output in model.outputs:
        for sub in output.submodels:
            findings += _self_gate(output.name, sub)
            if record_s is not None:
                findings += _time_constants(output.name, sub, model.sample_time_s, record_s)
        if ranges is not None and output.name in ranges:
            findings += _gains(output.name, output.submodels, ranges)
        if contributions is not None and output.name in contributions:
            findings += _cancelling(output.name, output.submodels, contributions[output.name])
    return findings


def _self_gate(output: str, sub: SubModel) -> list[Finding]:
    if sub.gate is None or sub.gate.signal != sub.input.signal or sub.input.minus is not None:
        return []
    return [
        Finding(
            Severity.ERROR,
            output,
            sub.name,
            f"its phase gate is its own input {sub.input.signal!r}: while the gate is open the "
            "gated input equals the input, so this sub-model and the ungated one on the same "
            "input are one regressor and can take any pair of cancelling gains",
            "Gate on another signal (e.g. the spindle speed for temperature inputs), or fit "
            "without --phase-gate",
        )
    ]


def _time_constants(
    output: str, sub: SubModel, sample_time_s: float, record_s: float
) -> list[Finding]:
    taus = time_constants_s(sub.tf, sample_time_s)
    if not taus.size:
        return []
    longest = float(taus.max())
    if longest > INTEGRATOR_RECORDS * record_s:
        return [
            Finding(
                Severity.ERROR,
                output,
                sub.name,
                f"time constant {_duration(longest)} is {longest / record_s:.0f} times the "
                f"{_duration(record_s)} calibration record: over the record it is an integrator, "
                "and outside it the sub-model drifts without bound",
                "Refit with fewer inputs, a lower order or --method lagbank (fixed time "
                "constants), or calibrate on a record several times longer",
            )
        ]
    if longest > record_s:
        return [
            Finding(
                Severity.WARNING,
                output,
                sub.name,
                f"time constant {_duration(longest)} is longer than the {_duration(record_s)} "
                "calibration record, which cannot pin it down",
                "Check it on a longer record, or limit the time constants",
            )
        ]
    return []


def _gains(
    output: str, subs: tuple[SubModel, ...], ranges: Mapping[str, tuple[float, float]]
) -> list[Finding]:
    low, high = ranges[output]
    output_range = high - low
    if not output_range > 0.0:
        return []
    groups: dict[tuple[object, ...], list[SubModel]] = {}
    for sub in subs:
        if sub.position is None and sub.input.minus is None and sub.input.signal in ranges:
            groups.setdefault(_group(sub), []).append(sub)
    findings = []
    for members in groups.values():
        gains = [_static_gain(sub) for sub in members]
        if any(g is None for g in gains):
            continue
        gain = float(sum(g for g in gains if g is not None))
        signal = members[0].input.signal
        lo, hi = ranges[signal]
        reach = abs(gain) * (hi - lo)
        ratio = reach / output_range
        if ratio <= GAIN_WARNING_RATIO:
            continue
        names = members[0].name if len(members) == 1 else f"{members[0].name} (+{len(members) - 1})"
        severity = Severity.ERROR if ratio > GAIN_ERROR_RATIO else Severity.WARNING
        findings.append(
            Finding(
                severity,
                output,
                names,
                f"static gain {gain:.4g} um per unit of {signal} over its calibration range "
                f"({hi - lo:.4g}) moves the output by {reach:.4g} um, {ratio:.0f} times the output's "
                f"whole range ({output_range:.4g} um): other sub-models must cancel it",
                "Select fewer, less collinear inputs (or --method lagbank, regularised), and judge "
                "the model by cross-validation",
            )
        )
    return findings


def _cancelling(
    output: str, subs: tuple[SubModel, ...], contributions: Mapping[str, np.ndarray]
) -> list[Finding]:
    groups: dict[tuple[object, ...], np.ndarray] = {}
    names: dict[tuple[object, ...], str] = {}
    for sub in subs:
        if sub.name in contributions:
            key = _group(sub)
            groups[key] = groups.get(key, 0.0) + np.asarray(contributions[sub.name], dtype=float)
            names.setdefault(key, sub.name)
    total = np.sum(list(groups.values()), axis=0) if groups else np.zeros(0)
    size = float(np.sqrt(np.mean(total**2))) if total.size else 0.0
    if size == 0.0:
        return []
    keys = list(groups)
    rms = {k: float(np.sqrt(np.mean(groups[k] ** 2))) for k in keys}
    findings = []
    for i, a in enumerate(keys):
        for b in keys[i + 1 :]:
            if min(rms[a], rms[b]) < CANCEL_SIZE_RATIO * size:
                continue
            together = float(np.sqrt(np.mean((groups[a] + groups[b]) ** 2)))
            if together < CANCEL_SUM_FRACTION * max(rms[a], rms[b]):
                findings.append(
                    Finding(
                        Severity.ERROR,
                        output,
                        f"{names[a]} + {names[b]}",
                        f"their contributions ({rms[a]:.3g} and {rms[b]:.3g} um RMS, against "
                        f"{size:.3g} um for the whole model) cancel to {together:.3g} um: the fit "
                        "balanced two large terms, which come apart on any other run",
                        "Drop one of the two inputs (they carry the same information) or use a "
                        "regularised fit (--method lagbank)",
                    )
                )
    return findings


def _duration(seconds: float) -> str:
    if seconds >= 2 * 365 * 86400:
        return f"{seconds / (365 * 86400):.0f} years"
    if seconds >= 2 * 86400:
        return f"{seconds / 86400:.1f} days"
    if seconds >= 7200:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds:.0f} s"
