"""The inputs checked against each other: a wrong sensor is found, stood in for, and trusted again only slowly."""

from __future__ import annotations

import numpy as np
import pytest
from structlog.testing import capture_logs

from compd.errors import CompdError
from compd.model.consistency import ConsistencyCheck, ConsistencyModel, fit_consistency
from compd.service.loop.plausibility import Plausibility, PlausibilitySettings
from compd.service.loop.signals import Checks, Health, Reading, SignalMonitor
from tests.model.test_consistency import CHECKED, SAMPLE_S, machine

UNITS = {name: "degC" for name in CHECKED} | {"spindle_speed_rpm": "rpm", "spindle_power_kw": "kW"}


@pytest.fixture(scope="module")
def model() -> ConsistencyModel:
    fitted = fit_consistency(machine(24, seed=1), CHECKED, SAMPLE_S)
    assert fitted is not None
    return fitted


class Bench:
    """The monitors and the plausibility stage, fed a record tick by tick (at its 10 s sample time)."""

    def __init__(
        self, model: ConsistencyModel, record: dict[str, np.ndarray], **settings: float
    ) -> None:
        self.record = record
        self.monitors = {
            name: SignalMonitor(
                name, Checks(min=-50, max=20_000, stale_s=60) if name in CHECKED else Checks()
            )
            for name in record
        }
        check = ConsistencyCheck(model, SAMPLE_S, frozenset(record))
        self.stage = Plausibility(
            check,
            self.monitors,
            UNITS,
            SAMPLE_S,
            PlausibilitySettings(**settings),  # type: ignore[arg-type]
        )

    def tick(self, k: int, wrong: dict[str, float] | None = None) -> dict[str, Reading]:
        read = {name: float(x[k]) for name, x in self.record.items()} | (wrong or {})
        readings = {name: m.update(k * SAMPLE_S, read[name]) for name, m in self.monitors.items()}
        return self.stage.judge(k * SAMPLE_S, readings, read)


def test_a_plausible_wrong_value_is_replaced_by_its_prediction_and_its_neighbours_stay_ok(
    model: ConsistencyModel,
) -> None:
    """+10 degC on the spindle sensor, within its range (no rate limit here): the others still agree."""
    record = machine(6, seed=5)
    bench = Bench(model, record)
    for k in range(720):
        assert all(r.health is Health.OK for r in bench.tick(k).values())
    for k in range(720, 1080):
        truth = float(record["T_spindle_degC"][k])
        out = bench.tick(k, {"T_spindle_degC": truth + 10.0})
        assert out["T_spindle_degC"].health is Health.ESTIMATED
        assert abs(out["T_spindle_degC"].value - truth) < 1.0
        assert all(out[n].health is Health.OK for n in CHECKED if n != "T_spindle_degC")


def test_a_sensor_that_returns_is_trusted_only_after_agreeing_for_confirm_ticks(
    model: ConsistencyModel,
) -> None:
    record = machine(4, seed=5)
    bench = Bench(model, record, confirm_ticks=12)
    for k in range(400):
        bench.tick(k)
    for k in range(400, 410):
        bench.tick(k, {"T_head_degC": float(record["T_head_degC"][k]) + 20.0})
    healths = [bench.tick(k)["T_head_degC"].health for k in range(410, 430)]
    assert healths[:11] == [Health.ESTIMATED] * 11
    assert healths[11] is Health.OK


def test_each_episode_is_one_error_line_at_its_start_and_one_at_its_end(
    model: ConsistencyModel,
) -> None:
    record = machine(4, seed=5)
    bench = Bench(model, record, confirm_ticks=5)
    with capture_logs() as logs:
        for k in range(400):
            bench.tick(k)
        for k in range(400, 460):
            bench.tick(k, {"T_column_degC": float(record["T_column_degC"][k]) - 15.0})
        for k in range(460, 500):
            bench.tick(k)
    errors = [e for e in logs if e["log_level"] == "error"]
    assert [e["signal"] for e in errors] == ["T_column_degC", "T_column_degC"]
    start, end = errors
    assert start["read"] == pytest.approx(record["T_column_degC"][400] - 15.0, abs=1e-3)
    assert abs(start["predicted"] - record["T_column_degC"][400]) < 1.0
    assert end["lasted_s"] == pytest.approx(64 * SAMPLE_S)
    assert bench.stage.count == 1


def test_without_signals_to_predict_from_the_input_faults_as_before(
    model: ConsistencyModel,
) -> None:
    """Only the speed is read besides the column, which follows the shop air: no stand-in."""
    record = {
        k: v for k, v in machine(2, seed=5).items() if k in ("T_column_degC", "spindle_speed_rpm")
    }
    bench = Bench(model, record)
    for k in range(100):
        bench.tick(k)
    out = bench.tick(100, {"T_column_degC": float("nan")})
    assert out["T_column_degC"].health is Health.HELD  # its own checks: held, then faulted


def test_a_returning_sensor_with_no_one_left_to_judge_it_is_used_as_without_a_consistency_model(
    model: ConsistencyModel,
) -> None:
    """Its stand-in's predictors all failed meanwhile: a reading passing its own checks ends the episode."""
    record = machine(2, seed=5)
    bench = Bench(model, record)
    for k in range(400):
        bench.tick(k)
    for k in range(400, 405):
        assert (
            bench.tick(k, {"T_spindle_degC": float("nan")})["T_spindle_degC"].health
            is Health.ESTIMATED
        )
    others = {name: float("nan") for name in record if name != "T_spindle_degC"}
    out = bench.tick(405, others)
    assert out["T_spindle_degC"].health is Health.OK
    assert out["T_spindle_degC"].value == pytest.approx(record["T_spindle_degC"][405])
    assert not bench.stage.episodes


def drifting(record: dict[str, np.ndarray], name: str, k: int, from_k: int, per_h: float) -> float:
    """``name``'s reading at tick ``k`` drifting by ``per_h`` (its unit an hour) from tick ``from_k``."""
    return float(record[name][k]) + per_h * max(k - from_k, 0) * SAMPLE_S / 3600.0


def test_a_slow_drift_is_caught_and_its_stand_in_carries_on_from_before_the_drift(
    model: ConsistencyModel,
) -> None:
    """+0.5 degC/h on the column from 2 h: a 300 s level would follow it; the hour's CUSUM does not."""
    record = machine(6, seed=5)
    bench = Bench(model, record)
    start = 720
    caught = None
    for k in range(len(record["T_column_degC"])):
        out = bench.tick(k, {"T_column_degC": drifting(record, "T_column_degC", k, start, 0.5)})
        assert all(out[n].health is Health.OK for n in CHECKED if n != "T_column_degC")
        if caught is None and out["T_column_degC"].health is Health.ESTIMATED:
            caught = k
    assert caught is not None and (caught - start) * SAMPLE_S <= 45 * 60, "caught within 45 min"
    error = abs(out["T_column_degC"].value - float(record["T_column_degC"][-1]))
    assert error < 0.3, "the stand-in carries on from the level before the drift began"
    assert bench.stage.drifts == 1


@pytest.mark.parametrize("name", CHECKED)
def test_a_drifting_input_is_blamed_not_the_neighbours_its_reading_predicts(
    model: ConsistencyModel, name: str
) -> None:
    """A drift moves every prediction the input takes part in; the input to blame is the one
    whose removal brings the others back."""
    record = machine(5, seed=6)
    bench = Bench(model, record)
    replaced: set[str] = set()
    for k in range(len(record[name])):
        out = bench.tick(k, {name: drifting(record, name, k, 720, 2.0)})
        replaced |= {n for n in CHECKED if out[n].health is Health.ESTIMATED}
    assert replaced == {name}


def test_an_input_its_redundant_partner_vouches_for_is_never_blamed(
    model: ConsistencyModel,
) -> None:
    record = machine(5, seed=6)
    bench = Bench(model, record)
    for k in range(len(record["T_spindle_degC"])):
        read = {"T_spindle_degC": drifting(record, "T_spindle_degC", k, 720, 2.0)}
        readings = {
            n: m.update(k * SAMPLE_S, read.get(n, float(record[n][k])))
            for n, m in bench.monitors.items()
        }
        values = {n: float(x[k]) for n, x in record.items()} | read
        out = bench.stage.judge(k * SAMPLE_S, readings, values, verified={"T_spindle_degC"})
        assert out["T_spindle_degC"].health is Health.OK


def test_a_stand_in_ends_on_evidence_not_on_a_reading_back_inside_the_wide_tolerance(
    model: ConsistencyModel,
) -> None:
    """After +20 degC, the head reads 2 degC high (inside the 3 degC tolerance): still stood in;
    back where it was before the episode, it is used again after confirm_ticks."""
    record = machine(4, seed=5)
    bench = Bench(model, record, confirm_ticks=12)
    for k in range(400):
        bench.tick(k)
    for k in range(400, 410):
        bench.tick(k, {"T_head_degC": float(record["T_head_degC"][k]) + 20.0})
    for k in range(410, 600):
        out = bench.tick(k, {"T_head_degC": float(record["T_head_degC"][k]) + 2.0})
        assert out["T_head_degC"].health is Health.ESTIMATED
        assert abs(out["T_head_degC"].value - record["T_head_degC"][k]) < 0.3
    healths = [bench.tick(k)["T_head_degC"].health for k in range(600, 620)]
    assert healths[:11] == [Health.ESTIMATED] * 11
    assert healths[11] is Health.OK


def test_a_person_may_vouch_for_a_sensor_and_it_is_used_from_its_next_good_reading(
    model: ConsistencyModel,
) -> None:
    """A recalibrated sensor that reads 2 degC differently comes back only on a person's word, logged."""
    record = machine(4, seed=5)
    bench = Bench(model, record)
    for k in range(400):
        bench.tick(k)
    assert "not stood in" in bench.stage.trust("T_head_degC")
    for k in range(400, 410):
        bench.tick(k, {"T_head_degC": float(record["T_head_degC"][k]) + 20.0})
    with capture_logs() as logs:
        bench.stage.trust("T_head_degC")
        for k in range(410, 700):
            out = bench.tick(k, {"T_head_degC": float(record["T_head_degC"][k]) + 2.0})
            assert out["T_head_degC"].health is Health.OK
    assert [e["event"] for e in logs if e["log_level"] in ("warning", "error")] == [
        "signal trusted by a person: its next good reading is used",
        "a person trusts it: its readings are used",
    ]
    with pytest.raises(CompdError, match="not checked"):
        bench.stage.trust("spindle_speed_rpm")


def test_two_sensors_failing_together_replace_no_healthy_one_and_both_come_back(
    model: ConsistencyModel,
) -> None:
    """Spindle +15 and head -25 degC for 10 min: each level survives the other's absence."""
    record = machine(4, seed=5)
    bench = Bench(model, record)
    for k in range(400):
        bench.tick(k)
    for k in range(400, 460):
        wrong = {
            "T_spindle_degC": float(record["T_spindle_degC"][k]) + 15.0,
            "T_head_degC": float(record["T_head_degC"][k]) - 25.0,
        }
        out = bench.tick(k, wrong)
        assert out["T_spindle_degC"].health is Health.ESTIMATED
        assert out["T_head_degC"].health is Health.ESTIMATED
        assert all(out[n].health is Health.OK for n in ("T_column_degC", "T_air_degC"))
    healths = [bench.tick(k) for k in range(460, 560)]
    assert all(r.health is Health.OK for r in healths[-1].values())
    assert not bench.stage.episodes


def test_with_no_one_left_to_judge_it_a_reading_that_jumped_is_not_trusted(
    model: ConsistencyModel,
) -> None:
    """Its predictors gone, the spindle returns 10 degC off the value in use: faulted, with the fix."""
    record = machine(2, seed=5)
    bench = Bench(model, record)
    for k in range(400):
        bench.tick(k)
    bench.tick(400, {"T_spindle_degC": float("nan")})
    others = {name: float("nan") for name in record if name != "T_spindle_degC"}
    for k in range(401, 420):
        out = bench.tick(k, others | {"T_spindle_degC": float(record["T_spindle_degC"][k]) + 10.0})
        assert out["T_spindle_degC"].health is Health.FAULTED
        assert "compd sensor trust T_spindle_degC" in out["T_spindle_degC"].reason
