"""The daemon's probe learner (compd.model.probelearner): regressors kept each tick, probes at their touch."""

from __future__ import annotations

import asyncio
import json
import math
import time

import numpy as np
import pytest

from compd.errors import ModelError
from compd.model.probebank import UpdaterBank
from compd.model.probelearner import RECENT_ROWS, OutputLearner, ShiftRefused
from compd.model.proberegressors import RegressorWindow, probed_thermal_error_um
from compd.model.probesettings import ProbeSettings
from compd.model.updateprior import BIAS, Prior

NAMES = ("a", "b", BIAS)
PRIOR = Prior(NAMES, np.diag([0.25, 0.25, 4.0]), residue_sigma_um=1.0, output_peak_um=30.0)
SETTINGS = ProbeSettings.defaults(PRIOR)


def regressor(t_s: float) -> np.ndarray:
    """Two slow contributions (um) and the 1 of the bias, as a thermal model gives them."""
    return np.array([20.0 * (1.0 - math.exp(-t_s / 7200.0)), 6.0 * math.sin(t_s / 5000.0), 1.0])


def ticked(seconds: int, start_s: float = 0.0, **window: float) -> OutputLearner:
    """A learner fed one tick a second for ``seconds`` (unscaled part 0.5 um)."""
    learner = OutputLearner(PRIOR, SETTINGS, RegressorWindow(**window))
    for k in range(seconds):
        learner.observe(start_s + k, regressor(start_s + k), 0.5)
    return learner


def test_the_probe_is_taken_with_the_regressor_of_its_touch_not_of_its_arrival() -> None:
    """A probe touched at 3600 s and arriving at 3660 s updates as the bare bank does at 3600 s."""
    learner = ticked(3661)
    truth = float(regressor(3600.0) @ np.array([1.3, 0.8, 2.0]))
    (step,) = learner.probe(3600.0, truth)
    bare = UpdaterBank(PRIOR, SETTINGS)
    times = np.arange(0.0, 3601.0, 60.0)  # the kept rows: one a minute
    rows = np.array([regressor(t) for t in times])
    (expected,) = bare.probe(3600.0, regressor(3600.0), truth, 0.5, recent=rows)
    assert step == expected
    np.testing.assert_allclose(learner.theta, bare.theta, rtol=1e-12)
    assert step.result == "accepted"
    assert step.predicted_um == pytest.approx(
        0.5 + 20.0 * (1 - math.exp(-0.5)) + 6 * math.sin(0.72)
    )


def test_between_kept_rows_the_regressor_is_interpolated() -> None:
    """At 90 s, between the rows of 60 and 120 s, the regressor is their mean."""
    learner = ticked(200)
    x, fixed = learner.regressor_at(90.0)
    np.testing.assert_allclose(x, (regressor(60.0) + regressor(120.0)) / 2, rtol=1e-12)
    assert fixed == 0.5
    latest, _ = learner.regressor_at(199.0 + 3.0)  # a touch 3 s after the last tick: that tick's
    np.testing.assert_array_equal(latest, regressor(199.0))


def test_a_touch_older_than_the_kept_rows_is_refused() -> None:
    """With 1 h kept, a touch 2 h back (or before any tick, or far ahead) is refused and changes nothing."""
    learner = ticked(3 * 3600, keep_s=3600.0)
    with pytest.raises(ModelError, match=r"older than the regressors kept \(from 7140.0 s, 1 h"):
        learner.probe(3600.0, 10.0)
    with pytest.raises(ModelError, match=r"60\.0 s after the last tick"):
        learner.probe(3 * 3600 - 1 + 60.0, 10.0)
    with pytest.raises(ModelError, match="no tick has been observed yet"):
        OutputLearner(PRIOR, SETTINGS).probe(0.0, 1.0)
    assert learner.adjustment_um(regressor(9000.0)) == 0.0


def test_the_kept_rows_are_bounded() -> None:
    """A day of 1 Hz ticks keeps one row a minute over 12 h: 721 rows, however long it runs."""
    learner = ticked(24 * 3600)
    times, rows, _ = learner._rows.view()
    assert len(times) == 721
    assert times[0] == 12 * 3600 - 60 and times[-1] == 24 * 3600 - 60
    assert rows.shape == (721, 3)
    assert len(learner._rows.t_s) <= 2048


def test_a_tick_costs_microseconds() -> None:
    """observe and adjustment_um at 81 parameters: well under 50 us a tick (a tick is 1 s)."""
    prior = Prior((*(f"g{i}" for i in range(80)), BIAS), np.eye(81), residue_sigma_um=1.0)
    learner = OutputLearner(prior, ProbeSettings.defaults(prior))
    x = np.append(np.linspace(0.0, 1.0, 80), 1.0)
    # CPU time, not wall time: what a tick costs, not how busy the host is.
    start = time.process_time()
    for k in range(20_000):
        learner.observe(float(k), x, 0.0)
        learner.adjustment_um(x)
    assert (time.process_time() - start) / 20_000 < 50e-6


def test_the_adjustment_is_zero_until_a_probe_is_taken() -> None:
    """0.0 before any probe and after a flagged one; x'(theta - theta0) after an accepted one."""
    learner = ticked(7200)
    x = regressor(7199.0)
    assert learner.adjustment_um(x) == 0.0
    (flagged,) = learner.probe(3600.0, 80.0)  # 60 um off: a mis-probe
    assert flagged.result == "flagged"
    assert learner.adjustment_um(x) == 0.0 and not learner.updated
    steps = learner.probe(7000.0, float(regressor(7000.0) @ [1.0, 1.0, 3.0]) + 0.5)
    assert [s.result for s in steps] == ["rejected", "accepted"]
    assert learner.adjustment_um(x) == pytest.approx(float(x @ (learner.theta - PRIOR.mean)))
    assert learner.adjustment_um(x) > 1.0
    assert learner.predict(x, 0.5) == pytest.approx(
        0.5 + float(x @ PRIOR.mean) + learner.adjustment_um(x)
    )


def test_two_probes_in_a_row_the_update_did_not_take_are_counted() -> None:
    """Two mis-probes of opposite signs: 2 in a row not taken (the status bit's count); a good one: 0."""
    learner = ticked(4 * 3600)
    learner.probe(3600.0, 80.0)
    assert learner.untaken_in_a_row == 1
    steps = learner.probe(7200.0, -60.0)
    assert [s.result for s in steps] == ["rejected", "flagged"]
    assert learner.untaken_in_a_row == 2 and learner.last_taken_s is None
    good = float(regressor(10800.0) @ PRIOR.mean) + 0.3 + 0.5
    assert [s.result for s in learner.probe(10800.0, good)] == ["rejected", "accepted"]
    assert learner.untaken_in_a_row == 0 and learner.last_taken_s == 10800.0


def test_the_departure_bound_holds_over_at_most_240_rows_since_the_last_probe() -> None:
    """The recent rows are those after the last probe taken, evenly thinned to RECENT_ROWS."""
    learner = ticked(10 * 3600, row_every_s=0.0, keep_s=math.inf)
    learner.probe(3600.0, float(regressor(3600.0) @ [1.1, 1.0, 1.0]))
    assert learner.since_s == 3600.0
    seen: list[np.ndarray] = []
    original = learner.updater.probe

    def spy(*args: object, recent: np.ndarray, **kwargs: object) -> object:
        seen.append(recent)
        return original(*args, recent=recent, **kwargs)  # type: ignore[arg-type]

    learner.updater.probe = spy  # type: ignore[method-assign]
    learner.probe(9 * 3600.0, float(regressor(9 * 3600.0) @ [1.1, 1.0, 1.0]))
    (recent,) = seen
    assert len(recent) == RECENT_ROWS  # 28800 rows, every 120th
    np.testing.assert_array_equal(recent[0], regressor(3601.0))
    np.testing.assert_array_equal(recent[-1], regressor(3601.0 + 239 * 120))


def test_the_state_round_trips_through_json_and_a_reset_returns_to_the_prior() -> None:
    """A restored learner adjusts as the saved one did; reset gives the prior's parameters back."""
    learner = ticked(7200)
    learner.probe(3600.0, float(regressor(3600.0) @ [1.2, 1.0, 1.5]))
    learner.probe(7000.0, 90.0)  # flagged: held as pending
    saved = json.loads(json.dumps(learner.state()))
    restored = OutputLearner.restore(PRIOR, SETTINGS, saved)
    x = regressor(7100.0)
    assert restored.adjustment_um(x) == learner.adjustment_um(x) != 0.0
    np.testing.assert_array_equal(restored.updater.covariance, learner.updater.covariance)
    assert restored.state() == learner.state()
    assert restored.last_taken_s == 3600.0 and restored.updater.last_time_s == 7000.0
    assert restored.untaken_in_a_row == 1
    restored.reset()
    assert restored.adjustment_um(x) == 0.0
    np.testing.assert_array_equal(restored.theta, PRIOR.mean)
    assert restored.updater.pending is None and restored.updater.last_time_s is None
    assert restored.last_taken_s is None and restored.untaken_in_a_row == 0


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda s: s.update(theta=[1.0, math.nan, 0.0]), "theta has a value that is not a finite"),
        (lambda s: s.update(theta=[1.0, 1.0]), r"theta has shape \(2,\), needs \(3,\)"),
        (lambda s: s["covariance"][0].__setitem__(1, 5.0), "covariance is not symmetric"),
        (lambda s: s.update(parameters=["a", "c", BIAS]), "the model's are"),
        (lambda s: s.update(last_time_s="soon"), "last_time_s is 'soon', not a finite number"),
        (lambda s: s.update(version=9), "version is 9, not 2"),
        (lambda s: s["pending"].update(x=[1.0, math.inf, 1.0]), "pending.x has a value"),
        (lambda s: s.update(untaken_in_a_row=-1), "untaken_in_a_row is -1, not a count"),
    ],
)
def test_a_damaged_state_is_refused_naming_what_is_wrong(change, message) -> None:
    """Every number finite, every shape right, the parameters the model's: else a ModelError saying which."""
    learner = ticked(7200)
    learner.probe(7000.0, 90.0)
    state = learner.state()
    change(state)
    with pytest.raises(ModelError, match=message):
        OutputLearner.restore(PRIOR, SETTINGS, state)


def _machine_truth(sign: float) -> tuple[float, float, float]:
    """On the simulated machine half an hour in: write ``sign * 3 um`` as compd does; the truth after."""
    from compd.service.loop.offsets import AxisPoint
    from compd.sim.plc.machine import ServedAxis, SimulatedMachine
    from compd.sim.plc.settings import SimulationDoc

    axis = AxisPoint("z", "disp_z_um", "plc", "offset_z", sign=sign, scale=10.0)
    machine = SimulatedMachine(
        SimulationDoc(hours=1.0, sample_time_s=10.0),
        signals=[],
        axes=[ServedAxis("z", "plc", "offset_z", "z", scale=10.0)],
        servers={},
    )
    asyncio.run(machine.advance_to(1800.0))
    written = machine.on_write("plc")

    def write_output(y_um: float) -> tuple[float, float, float]:
        raw = axis.encode(axis.sign * y_um)  # the compensator's target, as written
        written("offset_z", raw)
        true, offset, residue = machine.truth_now()["z"]
        assert offset == axis.decode(raw)
        return true, offset, residue

    true, offset, residue = write_output(3.0)  # a model off by whatever the machine does
    thermal = probed_thermal_error_um(residue, offset, sign)
    _, _, after = write_output(thermal)  # the model that had predicted it: nothing left
    return true, thermal, after


@pytest.mark.parametrize("sign", [-1.0, 1.0])
def test_the_probed_thermal_error_is_the_output_that_cancels_the_residue_on_the_simulated_machine(
    sign: float,
) -> None:
    """The residue with 3 um compensated plus the offset in force: the output whose offset leaves 0 um."""
    true, thermal, after = _machine_truth(sign)
    assert abs(true) > 1.0  # the machine has moved: the test says something
    assert after == pytest.approx(0.0, abs=1e-9)
    assert thermal == pytest.approx(-sign * true)
    with pytest.raises(ModelError, match="an axis sign is"):
        probed_thermal_error_um(1.0, 2.0, 0.5)


def test_an_update_beyond_the_learned_shift_bound_is_not_applied_unless_a_person_accepts_it() -> (
    None
):
    """A confirmed 40 um shift with max_shift_um 15: ShiftRefused, the learner as before; with
    accept_shift the same probe is taken, and that shift is the bound from then on."""
    settings = ProbeSettings.defaults(PRIOR, max_departure_um=100.0, max_shift_um=15.0)
    learner = OutputLearner(PRIOR, settings)
    for k in range(0, 7200):
        learner.observe(float(k), regressor(float(k)), 0.5)
    shifted = lambda t: 0.5 + float(regressor(t) @ PRIOR.mean) + 40.0  # noqa: E731
    assert learner.probe(3600.0, shifted(3600.0))[0].result == "flagged"
    before = learner.state()
    with pytest.raises(ShiftRefused, match=r"beyond the 15\.0 um .*--accept-shift"):
        learner.probe(4500.0, shifted(4500.0))
    assert learner.state() == before and learner.adjustment_um(regressor(5000.0)) == 0.0
    steps = learner.probe(4500.0, shifted(4500.0), accept_shift=True)
    assert steps[-1].result == "confirmed"
    assert learner.adjustment_um(regressor(4500.0)) == pytest.approx(40.0, abs=1.0)
    assert learner.accepted_shift_um == pytest.approx(abs(learner.theta[-1]))
    assert OutputLearner.restore(PRIOR, settings, learner.state()).accepted_shift_um > 15.0


def test_any_exception_in_the_update_leaves_the_learner_as_it_was() -> None:
    """A bug deep in the update (here an OverflowError): raised to the caller, nothing moved."""
    learner = ticked(4000)
    learner.probe(1800.0, float(regressor(1800.0) @ PRIOR.mean) + 2.0)
    before = learner.state()

    def overflow(*args: object) -> None:
        raise OverflowError("(34, 'Numerical result out of range')")

    learner.updater._take = overflow  # type: ignore[method-assign]
    with pytest.raises(OverflowError):
        learner.probe(3600.0, float(regressor(3600.0) @ PRIOR.mean) + 2.0)
    assert learner.state() == before


def _saved() -> dict[str, object]:
    learner = ticked(4000, start_s=1.7e9)
    learner.probe(1.7e9 + 1800.0, 0.5 + float(regressor(1.7e9 + 1800.0) @ PRIOR.mean) + 2.0)
    return json.loads(json.dumps(learner.state()))


def _absurd(change: str) -> dict[str, object]:
    state = _saved()
    theta, covariance = state["theta"], state["covariance"]
    assert isinstance(theta, list) and isinstance(covariance, list)
    if change == "gain":
        theta[0] = 1e20
    elif change == "bias":
        theta[-1] = 1e6
    elif change == "future":
        state["last_time_s"] = 9e9
    elif change == "indefinite":
        covariance[0][0] = -1.0
    elif change == "wide":
        covariance[1][1] = 1e12
    elif change == "accepted":
        state["accepted_shift_um"] = 1e9
    return state


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ("gain", r"the gain of a is 1e\+20, beyond its rails \[0, 3\]"),
        ("bias", r"the bias is 1e\+06 um, beyond 60 um"),
        ("future", r"last_time_s is \d+ s in the future"),
        ("indefinite", "not positive semi-definite"),
        ("wide", "the variance of b is 1e\\+12"),
        ("accepted", r"accepted_shift_um is 1e\+09"),
    ],
)
def test_a_restored_state_with_numbers_no_update_reaches_is_refused(
    change: str, problem: str
) -> None:
    """Finite but absurd (a gain of 1e20, a bias of 1 m, a probe in 2255, a covariance not positive
    definite or a million times its prior): a ModelError naming it, never a learner to run."""
    assert OutputLearner.restore(PRIOR, SETTINGS, _saved(), now_s=1.7e9 + 4000)  # as saved: fine
    with pytest.raises(ModelError, match=problem):
        OutputLearner.restore(PRIOR, SETTINGS, _absurd(change), now_s=1.7e9 + 4000)
