"""What the other sensors cannot verify: the detector's threshold times the model's static sensitivity."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.files.modelfile import load_model
from compd.model import Gate, InputSpec, Model, Output, Position, SubModel, compile_model
from compd.model.consistency import ConsistencyCheck, fit_consistency
from compd.model.verifiable import (
    Detection,
    default_tolerance_um,
    plausibility_detector,
    static_sensitivities,
    undetectable_error_um,
)
from tests.model.conftest import first_order
from tests.model.test_consistency import CHECKED, SAMPLE_S, machine

BUNDLED_MODEL = Path(__file__).resolve().parents[2] / "config" / "simulated_model.yaml"


def sub(
    signal: str, gain_um_per_unit: float, *, minus: str | None = None, gate: Gate | None = None,
    position: Position | None = None, gain_name: str | None = None,
) -> SubModel:  # fmt: skip
    tf = first_order(gain_um_per_unit, 0.9)
    return SubModel(signal, "e", InputSpec(signal, minus, 0.0), tf, 1.0, gate, gain_name, position)


def compiled(*outputs: tuple[str, tuple[SubModel, ...]]):  # type: ignore[no-untyped-def]
    return compile_model(Model("m", 1.0, tuple(Output(n, s) for n, s in outputs)))


def fixed(thresholds: dict[str, float]):  # type: ignore[no-untyped-def]
    return lambda name: Detection(thresholds.get(name, math.inf), "test")


def test_sensitivity_is_the_sum_of_static_gains_of_the_sub_models_reading_the_input() -> None:
    """Two sub-models on one input add; a ``minus`` input counts with the opposite sign."""
    model = compiled(
        ("disp_z_um", (sub("T_a", -3.0), sub("T_a", -5.0), sub("T_b", 2.0, minus="T_c")))
    )
    s = static_sensitivities(model)["disp_z_um"]
    assert_allclose([s["T_a"], s["T_b"], s["T_c"]], [-8.0, 2.0, -2.0])


def test_gated_sub_models_give_the_largest_sensitivity_over_gate_states() -> None:
    """Opposed terms under a gate: the gate state that leaves the larger magnitude is the sensitivity."""
    gate = Gate("speed_rpm", 0.0, True)
    model = compiled(("disp_z_um", (sub("T_a", -6.0), sub("T_a", 4.0, gate=gate))))
    assert static_sensitivities(model)["disp_z_um"]["T_a"] == pytest.approx(-6.0)
    model = compiled(("disp_z_um", (sub("T_a", 2.0), sub("T_a", 4.0, gate=gate))))
    assert static_sensitivities(model)["disp_z_um"]["T_a"] == pytest.approx(6.0)


def test_a_gain_schedule_row_that_scales_a_term_up_sets_the_sensitivity() -> None:
    """Each gain set is tried beside the model's own gains, and the largest magnitude kept."""
    model = compiled(("disp_z_um", (sub("T_a", 2.0, gain_name="g1"),)))
    assert static_sensitivities(model, [{"g1": 3.0}, {"g1": 0.5}])["disp_z_um"][
        "T_a"
    ] == pytest.approx(6.0)


def test_a_position_slope_has_no_static_weight_at_its_reference() -> None:
    """A sub-model multiplied by an axis position is left out: at its reference position it adds nothing."""
    model = compiled(
        ("disp_x_um", (sub("T_a", 1.0), sub("T_b", 0.5, position=Position("pos_x_mm", 0.0))))
    )
    assert "T_b" not in static_sensitivities(model)["disp_x_um"]


def test_undetectable_error_is_threshold_times_sensitivity_per_axis() -> None:
    """Each input the axis depends on: its threshold x |um per unit|, judged against the axis's tolerance."""
    model = compiled(
        ("disp_z_um", (sub("T_a", -8.0), sub("T_b", 0.5))), ("disp_x_um", (sub("T_a", 1.0),))
    )
    rows = undetectable_error_um(
        model, {"Z": "disp_z_um", "X": "disp_x_um"}, fixed({"T_a": 12.5, "T_b": 3.0}),
        {"Z": 5.0, "X": 20.0},
    )  # fmt: skip
    got = {(r.input, r.axis): (r.undetectable_um, r.exceeds) for r in rows}
    assert got == {
        ("T_a", "Z"): (pytest.approx(100.0), True),
        ("T_a", "X"): (pytest.approx(12.5), False),
        ("T_b", "Z"): (pytest.approx(1.5), False),
    }
    worst = next(r for r in rows if r.axis == "Z" and r.input == "T_a")
    assert "redundant sensor beside T_a" in worst.remedy and "probes on Z" in worst.remedy


def test_an_input_nothing_can_judge_is_entirely_unverifiable() -> None:
    """No detection: an infinite threshold, so any weight on the axis is beyond every tolerance."""
    model = compiled(("disp_z_um", (sub("T_a", 0.1),)))
    (row,) = undetectable_error_um(model, {"Z": "disp_z_um"}, fixed({}), {"Z": 5.0})
    assert row.undetectable_um == math.inf and row.exceeds


def test_the_plausibility_threshold_is_the_daemons_tolerance_from_the_signals_read() -> None:
    """k_sigma x the sigma the daemon's check computes from the signals read, never below the floor."""
    consistency = fit_consistency(machine(24, seed=1), CHECKED, SAMPLE_S)
    assert consistency is not None
    read = frozenset(consistency.signals) - {"T_head_degC"}
    detect = plausibility_detector(consistency, k_sigma=8.0, min_tolerance=0.01, available=read)
    check = ConsistencyCheck(consistency, SAMPLE_S, read)
    ok = np.array([name in read for name in consistency.signals])
    _, sigmas = check.predict_all(consistency.mean, ok)
    spindle = consistency.checked.index("T_spindle_degC")
    assert detect("T_spindle_degC").threshold == pytest.approx(8.0 * sigmas[spindle])
    assert detect("T_spindle_degC").by == "the other sensors"
    assert not detect("T_head_degC").verifiable  # not read: nothing to judge it by
    floor = plausibility_detector(consistency, k_sigma=8.0, min_tolerance=50.0)
    assert floor("T_spindle_degC").threshold == 50.0


def test_a_redundant_partner_verifies_an_input_to_the_pair_tolerance() -> None:
    """A partner's tolerance, when smaller, is the threshold; without a consistency model it is the only one."""
    detect = plausibility_detector(
        None, k_sigma=8.0, min_tolerance=3.0, partners={"T_a": ("T_a2", 0.5)}
    )
    assert detect("T_a") == Detection(0.5, "its redundant partner T_a2")
    assert not detect("T_b").verifiable
    assert "no consistency model" in detect("T_b").by


def test_the_default_tolerance_is_three_calibration_rms_with_a_floor() -> None:
    """3 x the calibration's RMS residue, at least 1 um; 5 um where the file records none."""
    assert default_tolerance_um(0.52) == pytest.approx(1.56)
    assert default_tolerance_um(0.1) == 1.0
    assert default_tolerance_um(None) == 5.0


def test_the_bundled_machine_cannot_verify_its_spindle_to_the_offset_it_needs() -> None:
    """The issue's figure: the spindle's 12.5 degC tolerance from the six signals read is about 100 um on Z."""
    model_file = load_model(BUNDLED_MODEL)
    read = {
        "spindle_speed_rpm", "spindle_power_kw", "T_ambient_degC", "T_spindle_degC",
        "T_headstock_degC", "T_column_front_degC",
    }  # fmt: skip
    detect = plausibility_detector(
        model_file.consistency(), k_sigma=8.0, min_tolerance=3.0, available=read
    )
    rows = undetectable_error_um(model_file.compile(), {"Z": "disp_z_um"}, detect, {"Z": 1.56})
    spindle = next(r for r in rows if r.input == "T_spindle_degC")
    assert spindle.detection.threshold == pytest.approx(12.5, abs=0.1)
    assert spindle.um_per_unit == pytest.approx(-7.77, abs=0.01)
    assert spindle.undetectable_um == pytest.approx(97.2, abs=0.5)
    assert spindle.exceeds
