"""The consistency model: each input predicted from the other signals, from any subset of them."""

from __future__ import annotations

import numpy as np
import pytest

from compd.errors import ModelFileError
from compd.files.modelfile import consistency_doc, parse_model
from compd.files.modelschema import ConsistencyDoc
from compd.files.modelwriter import consistency_lines
from compd.model.consistency import ConsistencyCheck, ConsistencyModel, fit_consistency

SAMPLE_S = 10.0


def machine(hours: float, seed: int, power_scale: float = 1.0) -> dict[str, np.ndarray]:
    """Three temperatures that follow a spindle's speed and the shop air, each with its own lag."""
    rng = np.random.default_rng(seed)
    n = round(hours * 3600 / SAMPLE_S)
    t = np.arange(n) * SAMPLE_S
    speed = np.repeat(rng.choice([0.0, 3000.0, 6000.0, 9000.0], size=n // 180 + 1), 180)[:n]
    air = 21.0 + 1.5 * np.sin(2 * np.pi * t / 86_400 + seed)
    heat = (speed / 1000.0) ** 1.5

    def lag(x: np.ndarray, tau_s: float) -> np.ndarray:
        a, y, out = np.exp(-SAMPLE_S / tau_s), x[0], np.empty_like(x)
        for k, v in enumerate(x):
            y = a * y + (1 - a) * v
            out[k] = y
        return out

    noise = lambda: rng.normal(0, 0.015, n)  # noqa: E731
    return {
        "spindle_speed_rpm": speed,
        "spindle_power_kw": power_scale * 0.05 * heat + rng.normal(0, 0.01, n),
        "T_air_degC": air + noise(),
        "T_spindle_degC": air + 0.6 * lag(heat, 900.0) + noise(),
        "T_head_degC": air + 0.3 * lag(heat, 2400.0) + noise(),
        "T_column_degC": air + 0.1 * lag(heat, 7200.0) + noise(),
    }


CHECKED = ["T_spindle_degC", "T_head_degC", "T_column_degC", "T_air_degC"]


@pytest.fixture(scope="module")
def model() -> ConsistencyModel:
    fitted = fit_consistency(machine(24, seed=1), CHECKED, SAMPLE_S)
    assert fitted is not None
    return fitted


def run(model: ConsistencyModel, record: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Each checked input's prediction minus its reading, tick by tick, at the model's sample time."""
    check = ConsistencyCheck(model, SAMPLE_S, frozenset(record))
    residues: dict[str, list[float]] = {name: [] for name in CHECKED}
    for k in range(len(record["T_air_degC"])):
        values = {name: float(x[k]) for name, x in record.items()}
        z = check.features(values)
        ok = check.usable(z, set())
        for name in CHECKED:
            p = check.predict(z, name, ok)
            residues[name].append(np.nan if p is None else values[name] - p.value)
        check.advance(z)
    return {name: np.array(r) for name, r in residues.items()}


def test_no_reading_of_a_record_it_was_not_fitted_on_falls_outside_the_daemons_tolerance(
    model: ConsistencyModel,
) -> None:
    """The daemon (:mod:`compd.service.loop.plausibility`) judges a reading by how far its residue moved
    from its recent level (averaged over minutes): within max(8 sigma, 1 degC), a third of the
    daemon's smallest tolerance, on a healthy machine's new record; the residue itself stays
    within three times that."""
    residues = run(model, machine(8, seed=7))
    for name in CHECKED:
        late = residues[name][360:]
        assert np.isfinite(late).mean() > 0.9, name  # none where the others explain too little
        late = late[np.isfinite(late)]
        tolerance = max(8 * model.sigma[model.checked.index(name)], 1.0)
        assert np.abs(late).max() < 3 * tolerance, name
        moved = late[30:] - late[:-30]  # 5 min at 10 s
        assert np.abs(moved).max() < tolerance, name


def test_the_held_out_sigma_is_not_the_in_sample_one(model: ConsistencyModel) -> None:
    """Judged on the other half of the calibration: finite, positive, and in the signal's unit."""
    assert all(0 < s < 1.0 for s in model.sigma)
    assert model.max_rate_per_s[model.checked.index("T_spindle_degC")] > 0


def test_a_predictor_outside_what_the_calibration_saw_is_left_out(
    model: ConsistencyModel,
) -> None:
    """Heavy cutting after a calibration in air: the power is 20 times higher; the spindle is not."""
    record = machine(8, seed=7, power_scale=20.0)
    check = ConsistencyCheck(model, SAMPLE_S, frozenset(record))
    for k in range(400):
        z = check.features({n: float(x[k]) for n, x in record.items()})
        check.advance(z)
    ok = check.usable(z, set())
    assert not ok[model.signals.index("spindle_power_kw")]
    p = check.predict(z, "T_spindle_degC", ok)
    assert p is not None and "spindle_power_kw" not in p.used
    assert abs(p.value - record["T_spindle_degC"][399]) < 5 * p.sigma


def test_no_prediction_when_the_remaining_signals_explain_too_little(
    model: ConsistencyModel,
) -> None:
    """The shop air does not follow the spindle's speed: from the speed alone, no stand-in."""
    record = machine(4, seed=3)
    check = ConsistencyCheck(model, SAMPLE_S, frozenset(["T_air_degC", "spindle_speed_rpm"]))
    z = check.features({n: float(x[0]) for n, x in record.items()})
    assert check.predict(z, "T_air_degC", check.usable(z, set())) is None


def model_file_with(doc: ConsistencyDoc) -> str:
    """A one-sub-model file carrying ``doc`` as its consistency block."""
    return "\n".join(
        [
            "schema: compd.model/1",
            "name: m",
            "sample_time_s: 10.0",
            "outputs:",
            "  y:",
            "    submodels:",
            "      - {name: s, effect: e, input: {signal: T_spindle_degC},",
            "         tf: {form: discrete, power_order: ascending, num: [1.0], den: [1.0]}}",
            *consistency_lines(doc),
        ]
    )


def test_the_model_file_carries_it_exactly(model: ConsistencyModel) -> None:
    loaded = parse_model(model_file_with(consistency_doc(model))).consistency()
    assert loaded is not None
    assert loaded.signals == model.signals and loaded.checked == model.checked
    np.testing.assert_allclose(loaded.cov, model.cov, rtol=1e-9)  # written to 10 digits
    assert loaded.sigma == model.sigma


def test_a_file_whose_covariance_does_not_fit_its_signals_is_refused(
    model: ConsistencyModel,
) -> None:
    doc = consistency_doc(model)
    text = model_file_with(doc.model_copy(update={"covariance": doc.covariance[:-1]}))
    with pytest.raises(ModelFileError, match="covariance"):
        parse_model(text, "bad.yaml")


def test_its_lags_are_the_default_lag_banks() -> None:
    from compd.model.consistency import TAUS_S
    from compd.model.lagbank import DEFAULT_TIME_CONSTANTS_S

    assert tuple(t for t in DEFAULT_TIME_CONSTANTS_S if t > 0) == TAUS_S


def test_a_signal_the_model_does_not_read_may_be_unusable(model: ConsistencyModel) -> None:
    """Naming a signal outside the consistency model as unusable (a second sensor held) changes nothing."""
    record = machine(1.0, 5)
    check = ConsistencyCheck(model, SAMPLE_S, frozenset(record))
    z = check.features({name: float(values[0]) for name, values in record.items()})
    assert (check.usable(z, {"T_spindle_b_degC"}) == check.usable(z, set())).all()
