"""The hidden-effect loop as a user runs it, where a residue ranking alone misleads (issue 21).

The user's loop: ``compd diagnose``, ``compd extend --effect`` the named
signal, again, at most three rounds, until diagnose names nothing or extend
refuses; never ``--force``. Two twin runs no ranking was tuned on:

- door openings, with a temperature beside the door (``T_feed_x_degC``: the
  enclosure air's and the Z screw's response to the door, and a little of the
  spindle's heat) that explains the residue as well as ``door_open`` itself;
- cutting heat and a drifting coolant at once (``cutting_coolant``), where
  the motor temperature follows the cutting power and the coolant's effect is
  partly taken by whatever is added first.

Measured (10 s data, base model on the 24 h calibration of seed 1, runs of
16 h, seed 2 to extend and seed 3 unseen): door loop 45.9 -> 90.1 -> 92.2 %
(door_open first, tied with T_feed_x_degC, which follows it); two effects
-10.4 -> 63.5 -> 93.0 % (spindle_power_kw, then T_coolant_degC with the
power's sub-models re-identified together with it). The code before issue
21 named T_feed_x_degC first (81.6 % of the residue against 81.4 %), and on
the two effects reached 63.5 -> 73.6 -> 81.5 % in three rounds.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from compd.sim import simulate_scenario
from compd.sim.scenarios import scenario_inputs
from compd.sim.sensors import PT100_NOISE_DEGC, lag
from compd.sim.thermal import simulate_record
from tests.clirun import compd
from tests.workflow.test_hidden_effects import SAMPLE_TIME_S, base_model, compd_json, twin

RUN_HOURS = 16
MAX_ROUNDS = 3


def door_run_with_a_temperature_beside_the_door(folder: Path, seed: int) -> Path:
    """The ``door`` run of ``seed`` and ``T_feed_x_degC``: a sensor beside the door."""
    path = folder / f"door-near-{seed}.csv"
    if path.exists():
        return path
    frame = simulate_scenario("door", RUN_HOURS, seed, SAMPLE_TIME_S)
    inputs = scenario_inputs("door", RUN_HOURS, seed, SAMPLE_TIME_S)
    shut = dataclasses.replace(inputs, door_open=np.zeros_like(inputs.door_open))
    opened, closed = simulate_record(inputs, SAMPLE_TIME_S), simulate_record(shut, SAMPLE_TIME_S)

    def door_part(node: str) -> np.ndarray:
        return np.asarray(opened.temperature(node) - closed.temperature(node))

    shaft = closed.temperature("shaft")
    true = inputs.T_ambient_degC[0] + door_part("air") + door_part("nut_z")
    true = true + 0.07 * (shaft - shaft[0])
    noise = np.random.default_rng([seed, 7]).normal(0.0, PT100_NOISE_DEGC, true.shape)
    frame["T_feed_x_degC"] = lag(true, 60.0, SAMPLE_TIME_S) + noise
    frame.to_csv(path, index=False, float_format="%.6f")
    return path


def user_loop(base: Path, run: Path, unseen: Path, folder: Path) -> list[dict]:
    """Diagnose, extend with the named signal, repeat; each round's diagnosis and unseen fit."""
    model, rounds = base, []
    for k in range(1, MAX_ROUNDS + 1):
        diagnosis = compd_json("diagnose", model, run)
        signal = diagnosis["missing_effect"]
        if signal is None:
            rounds.append({"diagnosis": diagnosis})
            break
        out = folder / f"{run.stem}-round{k}.yaml"
        try:
            extension = compd_json("extend", model, run, "--effect", signal,
                                   "--verify", unseen, "--out", out)  # fmt: skip
        except AssertionError:  # refused: the loop ends with the model it has
            rounds.append({"diagnosis": diagnosis, "refused": signal})
            break
        rounds.append({"diagnosis": diagnosis, "extension": extension})
        model = out
    return rounds


def unseen_fit(rounds: list[dict]) -> float:
    fits = [r["extension"]["verify"]["fit_percent_after"] for r in rounds if "extension" in r]
    return float(fits[-1]) if fits else -np.inf


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("loop_decisions")


@pytest.fixture(scope="module")
def base(folder: Path) -> Path:
    return base_model(folder, twin(folder, "calibration", 24, seed=1), "disp_z_um")


@pytest.fixture(scope="module")
def door_runs(folder: Path) -> tuple[Path, Path]:
    return tuple(door_run_with_a_temperature_beside_the_door(folder, s) for s in (2, 3))  # type: ignore[return-value]


def test_door_is_first_or_tied_with_the_temperature_that_follows_it(
    base: Path, door_runs: tuple[Path, Path]
) -> None:
    """diagnose ranks door_open first or presents it tied with T_feed_x_degC, with both extended fits."""
    diagnosis = compd_json("diagnose", base, door_runs[0])
    ranked = [c["signal"] for c in diagnosis["candidates"]]
    assert ranked[0] == "door_open" or set(diagnosis["tied"]) == {"door_open", "T_feed_x_degC"}
    assert {"door_open", "T_feed_x_degC"} <= set(ranked[:2]), ranked[:3]
    for c in diagnosis["candidates"][:2]:
        held = c["extended"]
        assert held["fit_percent_after"] > held["fit_percent_before"] + 20, c
        assert held["accepted"] and held["n_folds"] >= 3
    if diagnosis["tied"]:
        assert "explain the residue about equally" in diagnosis["verdict"]
        assert "--effect" in diagnosis["verdict"]


def test_door_loop_reaches_88_percent_on_an_unseen_run(
    base: Path, door_runs: tuple[Path, Path], folder: Path
) -> None:
    """The user loop on the door run fits the unseen run to >= 88 %."""
    rounds = user_loop(base, *door_runs, folder)
    assert unseen_fit(rounds) >= 88.0, [r["diagnosis"]["verdict"] for r in rounds]


def test_an_absorbed_candidate_stays_listed_with_its_new_figure(
    base: Path, door_runs: tuple[Path, Path], folder: Path
) -> None:
    """After an extension with T_feed_x_degC, door_open is still judged and listed, and vice versa."""
    run, _ = door_runs
    for first, other in (("T_feed_x_degC", "door_open"), ("door_open", "T_feed_x_degC")):
        out = folder / f"only-{first}.yaml"
        compd_json("extend", base, run, "--effect", first, "--out", out)
        listed = {c["signal"]: c for c in compd_json("diagnose", out, run)["candidates"]}
        assert other in listed and listed[other]["extended"] is not None, list(listed)[:5]


def test_two_effects_at_once_loop_reaches_90_percent_without_force(
    base: Path, folder: Path
) -> None:
    """Cutting heat and a drifting coolant: the user loop fits the unseen run to >= 90 % in <= 3 rounds."""
    run = twin(folder, "cutting_coolant", RUN_HOURS, seed=2)
    unseen = twin(folder, "cutting_coolant", RUN_HOURS, seed=3)
    rounds = user_loop(base, run, unseen, folder)
    assert unseen_fit(rounds) >= 90.0, [r["diagnosis"]["verdict"] for r in rounds]
    named = [r["extension"]["effect_signal"] for r in rounds if "extension" in r]
    assert {"spindle_power_kw", "T_coolant_degC"} <= set(named), named


def test_extend_tries_several_effects_and_records_them(
    base: Path, door_runs: tuple[Path, Path], folder: Path
) -> None:
    """--effect A,B judges each on the same folds, keeps the best by the rule and records both tried."""
    from compd.files.modelfile import load_model

    run, unseen = door_runs
    out = folder / "both-tried.yaml"
    result = compd_json("extend", base, run, "--effect", "T_feed_x_degC,door_open",
                        "--verify", unseen, "--out", out)  # fmt: skip
    tried = {t["signal"]: t for t in result["tried"]}
    assert set(tried) == {"T_feed_x_degC", "door_open"}
    assert result["effect_signal"] in tried and all(t["accepted"] for t in tried.values())
    (record,) = load_model(out).doc.provenance.extensions
    assert {t.signal for t in record.tried} == set(tried)
    assert [t.signal for t in record.tried if t.kept] == [result["effect_signal"]]
    assert result["verify"]["fit_percent_after"] >= 88.0
    html = folder / "both-tried.html"
    compd("report", out, unseen, "--out", html)
    table = html.read_text().split('class="extensions"')[1].split("</table>")[0]
    assert "signals tried" in html.read_text() and all(s in table for s in tried)
    auto = compd_json("extend", base, run, "--effect", "auto", "--out", folder / "auto.yaml")
    assert len(auto["tried"]) == 3 and auto["effect_signal"] in {"door_open", "T_feed_x_degC"}


def test_an_effect_on_another_axis_is_refused_with_the_rule_and_its_figures(
    base: Path, folder: Path
) -> None:
    """On a feed run, after feed_z, feed_x (it moves X, not Z) is refused, naming the share and the folds."""
    run = twin(folder, "feed", RUN_HOURS, seed=2)
    first = folder / "feed-z.yaml"
    compd_json("extend", base, run, "--effect", "feed_z_mm_per_min", "--out", first)
    with pytest.raises(AssertionError) as refused:
        compd_json(
            "extend", first, run, "--effect", "feed_x_mm_per_min", "--out", folder / "x.yaml"
        )
    message = str(refused.value)
    assert (
        "does not help enough" in message and "of the remaining error on held-out folds" in message
    )
    assert "folds" in message and "at least 10 %" in message
    assert not (folder / "x.yaml").exists()


def test_a_signal_that_only_supplies_an_offset_is_refused(
    base: Path, door_runs: tuple[Path, Path], folder: Path
) -> None:
    """On the door run the coolant is constant but for noise: its sub-model would be an offset, refused."""
    run, _ = door_runs
    out = folder / "coolant-offset.yaml"
    with pytest.raises(AssertionError) as refused:
        compd_json("extend", base, run, "--effect", "T_coolant_degC", "--out", out)
    assert "a constant offset alone would leave" in str(refused.value) and not out.exists()
