"""How well a model matches measurement, in the papers' terms.

``fit %`` is Horejs 2015 eq. 2 / Post-process 2024 eq. 4 (the NRMSE fit of MATLAB's
``compare``)::

    fit = (1 - ||Y - Y_hat|| / ||Y - mean(Y)||) * 100

and the ``residue = Y - Y_hat`` (Horejs 2015 eq. 3) is the error that would
remain on the machine after compensation. Uncompensated figures are those of
``Y`` itself: the error with no compensation at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def fit_percent(measured: np.ndarray, simulated: np.ndarray) -> float:
    """Horejs 2015 eq. 2 in percent; NaN when the measurement does not vary (the ratio is undefined)."""
    measured = np.asarray(measured, dtype=float)
    spread = np.linalg.norm(measured - measured.mean())
    if spread == 0.0:
        return float("nan")
    return float(
        (1.0 - np.linalg.norm(measured - np.asarray(simulated, dtype=float)) / spread) * 100.0
    )


@dataclass(frozen=True)
class ErrorStats:
    """Size of an error signal, all in um."""

    rms_um: float
    peak_to_peak_um: float
    max_abs_um: float
    mean_um: float

    @classmethod
    def of(cls, error_um: np.ndarray) -> ErrorStats:
        error_um = np.asarray(error_um, dtype=float)
        return cls(
            rms_um=float(np.sqrt(np.mean(error_um**2))),
            peak_to_peak_um=float(np.ptp(error_um)),
            max_abs_um=float(np.max(np.abs(error_um))),
            mean_um=float(np.mean(error_um)),
        )


def reduction_percent(before: float, after: float) -> float:
    """How much of ``before`` compensation removes: ``(1 - after/before) * 100``; NaN if before is 0."""
    return float("nan") if before == 0.0 else float((1.0 - after / before) * 100.0)


@dataclass(frozen=True)
class Comparison:
    """A model's output against a measured column, over one record."""

    output: str
    fit_percent: float
    residue: ErrorStats
    uncompensated: ErrorStats

    @classmethod
    def of(cls, output: str, measured_um: np.ndarray, predicted_um: np.ndarray) -> Comparison:
        measured_um = np.asarray(measured_um, dtype=float)
        return cls(
            output=output,
            fit_percent=fit_percent(measured_um, predicted_um),
            residue=ErrorStats.of(measured_um - predicted_um),
            uncompensated=ErrorStats.of(measured_um),
        )

    @property
    def rms_reduction_percent(self) -> float:
        return reduction_percent(self.uncompensated.rms_um, self.residue.rms_um)

    @property
    def peak_to_peak_reduction_percent(self) -> float:
        return reduction_percent(self.uncompensated.peak_to_peak_um, self.residue.peak_to_peak_um)

    def as_dict(self) -> dict[str, float | str]:
        """The JSON shape scripts rely on (key names are a contract)."""
        return {
            "output": self.output,
            "fit_percent": self.fit_percent,
            "rms_um": self.residue.rms_um,
            "peak_to_peak_um": self.residue.peak_to_peak_um,
            "max_abs_um": self.residue.max_abs_um,
            "mean_um": self.residue.mean_um,
            "uncompensated_rms_um": self.uncompensated.rms_um,
            "uncompensated_peak_to_peak_um": self.uncompensated.peak_to_peak_um,
            "uncompensated_max_abs_um": self.uncompensated.max_abs_um,
            "rms_reduction_percent": self.rms_reduction_percent,
            "peak_to_peak_reduction_percent": self.peak_to_peak_reduction_percent,
        }
