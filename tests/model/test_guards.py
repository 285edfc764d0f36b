"""Guard rails: a model implausible for its calibration data is named, sub-model by sub-model, with a fix."""

from __future__ import annotations

import numpy as np

from compd.model.guards import Severity, check_model
from compd.model.structure import Gate, GateTarget, InputSpec, Model, Output, SubModel
from compd.model.transfer import DiscreteTF

DT_S = 15.0
RECORD_S = 32 * 3600.0


def _lag(gain: float, tau_s: float) -> DiscreteTF:
    pole = np.exp(-DT_S / tau_s)
    return DiscreteTF.from_coefficients([0.0, gain * (1 - pole)], [1.0, -pole])


def _model(*subs: SubModel) -> Model:
    return Model("m", DT_S, (Output("disp_um", subs),))


RANGES = {"disp_um": (-70.0, 20.0), "T1": (20.0, 26.0), "T2": (20.0, 26.0), "speed": (0.0, 5000.0)}


def test_a_plausible_model_has_no_findings() -> None:
    """A few um/K with hour-long lags on a 32 h record passes."""
    model = _model(SubModel("T1", "e", InputSpec("T1"), _lag(5.0, 3600.0)))
    assert check_model(model, ranges=RANGES, record_s=RECORD_S) == []


def test_an_eight_year_time_constant_is_an_error() -> None:
    """A time constant thousands of records long makes the sub-model an integrator."""
    model = _model(SubModel("T16", "e", InputSpec("T1"), _lag(-1.1e5, 2.5e8)))
    findings = check_model(model, ranges=RANGES, record_s=RECORD_S)
    assert {f.severity for f in findings} == {Severity.ERROR}
    assert any("years" in f.message and f.submodel == "T16" for f in findings)
    assert any("static gain" in f.message for f in findings)


def test_a_time_constant_longer_than_the_record_is_a_warning() -> None:
    """Two days on a 32 h record: the data cannot pin it down, but it is no integrator."""
    model = _model(SubModel("T1", "e", InputSpec("T1"), _lag(1.0, 2 * 86400.0)))
    (finding,) = check_model(model, record_s=RECORD_S)
    assert finding.severity is Severity.WARNING and "longer than" in finding.message


def test_the_lags_of_one_input_are_judged_together() -> None:
    """A lag bank's large lags that mostly cancel within one input are one plausible gain."""
    model = _model(
        SubModel("T1_lag_1h", "e", InputSpec("T1"), _lag(80.0, 3600.0)),
        SubModel("T1_lag_3h", "e", InputSpec("T1"), _lag(-75.0, 10800.0)),
    )
    assert check_model(model, ranges=RANGES, record_s=RECORD_S) == []


def test_a_gate_on_its_own_input_is_refused() -> None:
    """``u * (u > 0)`` equals ``u`` while the gate is open: heating and cooling cannot be told apart."""
    gate = Gate("speed", 0.0, True, GateTarget.INPUT)
    model = _model(
        SubModel("speed", "e", InputSpec("speed"), _lag(-154.0, 3600.0)),
        SubModel("speed_heating", "e", InputSpec("speed"), _lag(154.0, 3600.0), gate=gate),
    )
    findings = check_model(model)
    assert [f.submodel for f in findings] == ["speed_heating"]
    assert findings[0].severity is Severity.ERROR and "own input" in findings[0].message


def test_two_large_contributions_that_cancel_are_named() -> None:
    """Contributions of hundreds of um that sum to the output's few um are a fragile balance."""
    t = np.linspace(0, 1, 500)
    big = 300.0 * np.sin(6 * t)
    model = _model(
        SubModel("T1", "e", InputSpec("T1"), _lag(50.0, 3600.0)),
        SubModel("T2", "e", InputSpec("T2"), _lag(-50.0, 3600.0)),
    )
    contributions = {"disp_um": {"T1": big + 2.0 * t, "T2": -big}}
    findings = check_model(model, contributions=contributions)
    assert [f.submodel for f in findings] == ["T1 + T2"] and "cancel" in findings[0].message
