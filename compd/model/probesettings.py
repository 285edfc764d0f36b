"""The probe update's settings and rails: probe noise, drift, rejection, departure and the rails of each parameter.

The documented defaults scale with the calibration (its residue sigma, its
model's largest output, its residue's transient variance over the probe
interval); :class:`~compd.model.probeupdate.ProbeUpdater` takes them as
given. numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from compd.model.updateprior import Prior

__all__ = [
    "COEFFICIENT_BOUND_SD",
    "DEFAULT_PROBE_INTERVAL_S",
    "DEFAULT_PROBE_NOISE_UM",
    "MAX_PROBE_UM",
    "ProbeSettings",
    "max_probe_um",
    "parameter_bounds",
]

#: Default probe noise, um (issue 35's feasibility study).
DEFAULT_PROBE_NOISE_UM = 0.5
#: The probe interval the settings assume when none is given (the daemon's ``probes.every_h``).
DEFAULT_PROBE_INTERVAL_S = 7200.0
#: Default drift: the output may move this many calibration residue sigmas per sqrt(hour).
DEFAULT_DRIFT_SIGMAS_PER_SQRT_H = 0.3
#: Default rejection threshold, in predicted standard deviations of the innovation.
DEFAULT_REJECT_SIGMA = 4.0
#: Default guard rails of every gain (the file's gain is 1).
DEFAULT_GAIN_BOUNDS = (0.0, 3.0)
#: Default bound on the updated prediction's departure from the calibration model's: this
#: share of the largest output the calibration model gave (the compensation's own scale; the
#: calibration residue is in-sample and says nothing of the error on new programmes), never
#: below :data:`MIN_DEPARTURE_UM`; :data:`UNKNOWN_DEPARTURE_UM` when the scale is unknown.
DEFAULT_DEPARTURE_SHARE = 0.5
MIN_DEPARTURE_UM = 5.0
UNKNOWN_DEPARTURE_UM = 25.0
#: An innovation is flagged beyond ``reject_sigma`` predicted sigmas and beyond this share of
#: the calibration model's largest output (a model off by its structural error on a new
#: programme is not a mis-probe), never below :data:`MIN_REJECT_FLOOR_UM`. A flagged probe
#: leaves the probe due, so the PLC probes again at its next chance and confirms it within
#: minutes (compare --probe-every draws that probe 15 min later). Chosen on the random machines
#: and the shared record (benchmarks/bench_probes.py, re-probing on): 0.35 beats open loop on
#: 83 / 58 / 25 % of machines at 2 / 4 / 8 h (0.5: 83 / 59 / 26 %, 0.25: 83 / 58 / 25 % but
#: the shared record's 4 h gain lost, 65.1 -> 58.9 %), and flags a 50 um mis-probe on the
#: bundled model (its largest output 99 um; 0.5 would not).
DEFAULT_REJECT_FLOOR_SHARE = 0.35
MIN_REJECT_FLOOR_UM = 2.0
UNKNOWN_REJECT_FLOOR_UM = 10.0
#: A probe measures a thermal error or what is left of one: beyond 1 mm it is a typo, a unit
#: mistake (mm for um) or an attack, never a machine tool's thermal drift ...
MAX_PROBE_UM = 1000.0
#: ... nor beyond this many times the largest output the calibration model gave.
MAX_PROBE_PEAKS = 10.0


#: In the coefficients form each coefficient stays within this many prior standard deviations
#: of the file's: a rail against a runaway, not a shrinkage (the departure bound and the reach
#: limit hold the predictions).
COEFFICIENT_BOUND_SD = 6.0


def parameter_bounds(prior: Prior, settings: ProbeSettings) -> tuple[np.ndarray, np.ndarray]:
    """Each parameter's rails but the bias's: (low, high), both (p - 1,).

    Gains: ``settings.gain_bounds``; coefficients: the file's
    ``+- COEFFICIENT_BOUND_SD`` prior standard deviations.
    """
    p = len(prior.names) - 1
    if prior.coefficients is None:
        low, high = settings.gain_bounds
        return np.full(p, float(low)), np.full(p, float(high))
    spread = COEFFICIENT_BOUND_SD * np.sqrt(np.maximum(np.diag(prior.covariance)[:-1], 0.0))
    return prior.coefficients - spread, prior.coefficients + spread


def max_probe_um(prior: Prior) -> float:
    """The largest |measured value| a probe may have (um): :data:`MAX_PROBE_UM`, or
    :data:`MAX_PROBE_PEAKS` times the calibration's largest output where that is smaller."""
    peak = prior.output_peak_um
    return min(MAX_PROBE_UM, MAX_PROBE_PEAKS * peak) if peak > 0 else MAX_PROBE_UM


@dataclass(frozen=True)
class ProbeSettings:
    """The update's settings: probe noise (um), drift (um per sqrt h), rails."""

    probe_noise_um: float
    drift_um_per_sqrt_h: float
    max_departure_um: float
    reject_floor_um: float = 0.0
    reject_sigma: float = DEFAULT_REJECT_SIGMA
    gain_bounds: tuple[float, float] = DEFAULT_GAIN_BOUNDS
    #: The calibration residue's variance that does not persist over the probe interval (um^2,
    #: :func:`~compd.model.updateprior.transient_variances`): the bank's ``gains`` member counts
    #: it as probe noise (:data:`compd.model.probebank.MEMBERS`).
    transient_variance_um2: float = 0.0
    #: The largest learned shift (the bias, um) the probes may reach without a person
    #: (:class:`~compd.model.probelearner.OutputLearner` holds it; the gains have their
    #: rails); inf: unbounded. :meth:`defaults` makes it twice ``max_departure_um``.
    max_shift_um: float = math.inf

    @classmethod
    def defaults(
        cls, prior: Prior, *, interval_s: float = DEFAULT_PROBE_INTERVAL_S, **overrides: float
    ) -> ProbeSettings:
        """The documented defaults, scaled by the prior's calibration residue sigma; probes
        about ``interval_s`` apart (the transient variance over it)."""
        sigma, peak = prior.residue_sigma_um, prior.output_peak_um
        values: dict[str, float] = {
            "probe_noise_um": DEFAULT_PROBE_NOISE_UM,
            "transient_variance_um2": prior.transient_variance_um2(interval_s),
            "drift_um_per_sqrt_h": DEFAULT_DRIFT_SIGMAS_PER_SQRT_H * sigma,
            "max_departure_um": (
                max(MIN_DEPARTURE_UM, DEFAULT_DEPARTURE_SHARE * peak)
                if peak > 0
                else UNKNOWN_DEPARTURE_UM
            ),
            "reject_floor_um": (
                max(MIN_REJECT_FLOOR_UM, DEFAULT_REJECT_FLOOR_SHARE * peak)
                if peak > 0
                else UNKNOWN_REJECT_FLOOR_UM
            ),
        }
        values.update(overrides)
        # A learned shift (the bias) as large as everything the calibration model compensates
        # (twice the departure rail: its largest output) is a new calibration or a crash for a
        # person to judge, not a drift for a filter to follow. Half of it (the rail itself)
        # refused 2 of 250 probes on 20 random machines (benchmarks/bench_probes.py, seeds
        # 4-23) and cost the 2 h median 1.2 points; this refused none.
        values.setdefault("max_shift_um", 2.0 * values["max_departure_um"])
        return cls(**values)  # type: ignore[arg-type]
