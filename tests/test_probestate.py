"""The probe files of the state directory (compd.files.probestate): learned states per model sha256, the probe log."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from compd.files.probestate import (
    ProbeRecord,
    append_record,
    learned_path,
    read_log,
    reset_learned,
    restore_learners,
    save_learned,
)
from compd.model.probelearner import OutputLearner
from compd.model.probesettings import ProbeSettings
from compd.model.updateprior import BIAS, Prior

SHA = "a" * 64
OTHER = "b" * 64
PRIOR = Prior(("heat", "air", BIAS), np.diag([0.09, 0.09, 4.0]), residue_sigma_um=1.0)
SETUPS = {"disp_z_um": (PRIOR, ProbeSettings.defaults(PRIOR))}


def regressor(t_s: float) -> np.ndarray:
    return np.array([12.0 * (1.0 - math.exp(-t_s / 3600.0)), -3.0 * math.sin(t_s / 9000.0), 1.0])


def taught() -> OutputLearner:
    """A learner that took one probe 1.5 um above its prediction at 1 h."""
    learner = OutputLearner(*SETUPS["disp_z_um"])
    for k in range(0, 7200, 10):
        learner.observe(1.7e9 + k, regressor(k), 0.0)
    (step,) = learner.probe(1.7e9 + 3600, float(regressor(3600) @ PRIOR.mean) + 1.5)
    assert step.result == "accepted"
    return learner


def test_what_was_learned_survives_a_restart(tmp_path) -> None:
    """Saved, then restored for the same model: the same adjustment; no temporary file is left."""
    learner = taught()
    path = save_learned(tmp_path, SHA, {"disp_z_um": learner}, now_s=1.7e9 + 7200)
    assert path == tmp_path / "probes" / f"{SHA}.json"
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]
    restored = restore_learners(tmp_path, SHA, SETUPS)
    assert restored.restored == ("disp_z_um",) and restored.problem is None
    x = regressor(5000)
    assert restored.learners["disp_z_um"].adjustment_um(x) == learner.adjustment_um(x) != 0.0
    # At the probe's instant: the part of the 1.5 um the update took (probe noise 0.5 um).
    at_probe = restored.learners["disp_z_um"].adjustment_um(regressor(3600))
    assert 1.0 < at_probe < 1.5


def test_another_model_starts_from_its_prior(tmp_path) -> None:
    """The state is kept per sha256: a model with another one finds nothing, and adjusts by 0."""
    save_learned(tmp_path, SHA, {"disp_z_um": taught()}, now_s=1.7e9)
    restored = restore_learners(tmp_path, OTHER, SETUPS)
    assert restored.restored == () and restored.problem is None
    assert restored.learners["disp_z_um"].adjustment_um(regressor(5000)) == 0.0


@pytest.mark.parametrize(
    ("damage", "problem"),
    [
        (lambda t: t.replace('"theta": [', '"theta": [NaN, ', 1), "NaN is not a number"),
        (
            lambda t: t.replace('"theta": [', '"theta": [1.0, ', 1),
            r"outputs\.disp_z_um: theta has shape \(4,\)",
        ),
        (
            lambda t: t.replace(SHA, OTHER),
            "holds the state of model bbbbbbbbbbbb, not aaaaaaaaaaaa",
        ),
        (lambda t: t[: len(t) // 2], "not JSON"),
        (
            lambda t: t.replace('"saved_s": 1', '"saved_s": 1' + "0" * 400, 1),
            "saved_s is an integer of",
        ),
    ],
)
def test_a_damaged_state_is_set_aside_and_the_model_runs_on_its_prior(
    tmp_path, damage, problem
) -> None:
    """A NaN, a wrong shape, another model's state, half a file: renamed beside, the prior used, why said."""
    path = save_learned(tmp_path, SHA, {"disp_z_um": taught()}, now_s=1700000000)
    path.write_text(damage(path.read_text()))
    restored = restore_learners(tmp_path, SHA, SETUPS)
    assert restored.problem is not None
    assert restored.problem.startswith(f"{path}: ")
    assert __import__("re").search(problem, restored.problem)
    assert restored.set_aside_as is not None and restored.set_aside_as.name.startswith(
        f"{SHA}.json.corrupt-"
    )
    assert not path.exists() and restored.set_aside_as.exists()
    assert restored.learners["disp_z_um"].adjustment_um(regressor(5000)) == 0.0


def test_a_reset_deletes_what_was_learned(tmp_path) -> None:
    """After a reset the model runs on its prior; a second reset finds nothing."""
    save_learned(tmp_path, SHA, {"disp_z_um": taught()}, now_s=1.7e9)
    assert reset_learned(tmp_path, SHA) is True
    assert not learned_path(tmp_path, SHA).exists()
    assert reset_learned(tmp_path, SHA) is False
    assert restore_learners(tmp_path, SHA, SETUPS).restored == ()
    with pytest.raises(ValueError, match="64 lower-case hex digits"):
        learned_path(tmp_path, "../state")


def test_the_probe_log_keeps_every_step_and_skips_a_torn_line(tmp_path) -> None:
    """Each step a line, read back as written; a torn line is named, the lines after it still read."""
    learner = OutputLearner(*SETUPS["disp_z_um"])
    for k in range(0, 7200, 10):
        learner.observe(1.7e9 + k, regressor(k), 0.0)
    steps = learner.probe(1.7e9 + 3600, 60.0)  # a mis-probe: flagged
    steps += learner.probe(1.7e9 + 7000, float(regressor(7000) @ PRIOR.mean) + 0.4)
    records = [
        ProbeRecord.of_step(
            s, model_sha256=SHA, output="disp_z_um", source="plc", axis="z", offset_um=-9.5
        )
        for s in steps
    ]
    assert [r.result for r in records] == ["flagged", "rejected", "accepted"]
    for record in records[:2]:
        append_record(tmp_path, record)
    with (tmp_path / "probes" / "log.jsonl").open("a") as f:
        f.write('{"touched_s": 17')  # a crash mid-line
        f.write("\n")
    append_record(tmp_path, records[2])
    log = read_log(tmp_path)
    assert log.records == tuple(records)
    (torn,) = log.unreadable
    assert torn.startswith(f"{tmp_path / 'probes' / 'log.jsonl'}: line 3: not JSON")
    accepted = log.records[2]
    assert accepted.innovation_before_um == pytest.approx(0.4, abs=1e-9)
    assert accepted.predicted_after_um == pytest.approx(
        accepted.measured_um - accepted.innovation_after_um
    )
    assert records[1].predicted_sd_um is None  # a rejected probe has no sd: no NaN in the file
    line = json.loads((tmp_path / "probes" / "log.jsonl").read_text().splitlines()[0])
    assert line["result"] == "flagged" and line["axis"] == "z" and "reason" not in line


def test_a_log_line_with_a_bad_number_is_named(tmp_path) -> None:
    """NaN, a string for a number, an unknown result: each line named with its key."""
    path = tmp_path / "probes" / "log.jsonl"
    path.parent.mkdir()
    base = {"touched_s": 1.0, "model_sha256": SHA, "output": "z", "source": "cli"}
    lines = [
        json.dumps(base | {"result": "accepted", "measured_um": "high"}),
        json.dumps(base | {"result": "accepted"}).replace("1.0", "NaN"),
        json.dumps(base | {"result": "guessed"}),
        json.dumps(base | {"result": "reset", "reason": "compd model reset"}),
    ]
    path.write_text("\n".join(lines) + "\n")
    log = read_log(tmp_path)
    assert [r.result for r in log.records] == ["reset"]
    assert [u.split(": ", 1)[1] for u in log.unreadable] == [
        "line 1: measured_um is 'high', not a number",
        "line 2: NaN is not a number a compd file holds",
        "line 3: result is 'guessed', not one of accepted, flagged, confirmed, rejected, refused, reset",
    ]


@pytest.mark.parametrize(
    ("field", "value", "problem"),
    [
        ("theta", [1e20, 1.0, 0.0], r"outputs\.disp_z_um: the gain of heat is 1e\+20"),
        ("theta", [1.0, 1.0, 1e6], r"outputs\.disp_z_um: the bias is 1e\+06 um"),
        ("last_time_s", 9e9, r"outputs\.disp_z_um: last_time_s is \d+ s in the future"),
    ],
)
def test_a_state_with_absurd_numbers_is_set_aside_and_the_model_runs_on_its_prior(
    tmp_path, field, value, problem
) -> None:
    """Finite numbers no update reaches (the issue's bias 1e6, gain 1e20, a probe in 2255): set
    aside as a damaged file is, the prior used, never "probe updates resumed" with them."""
    path = save_learned(tmp_path, SHA, {"disp_z_um": taught()}, now_s=1.7e9 + 7200)
    data = json.loads(path.read_text())
    data["outputs"]["disp_z_um"][field] = value
    path.write_text(json.dumps(data))
    restored = restore_learners(tmp_path, SHA, SETUPS, now_s=1.7e9 + 7200)
    assert restored.problem is not None and __import__("re").search(problem, restored.problem)
    assert restored.restored == () and not path.exists()
    assert restored.set_aside_as is not None and restored.set_aside_as.exists()
    assert restored.learners["disp_z_um"].adjustment_um(regressor(5000)) == 0.0


def test_a_state_saved_in_the_future_is_set_aside(tmp_path) -> None:
    """saved_s beyond the clock's skew: not this machine's past (a clock wound back, a forged file)."""
    save_learned(tmp_path, SHA, {"disp_z_um": taught()}, now_s=1.7e9 + 86400)
    restored = restore_learners(tmp_path, SHA, SETUPS, now_s=1.7e9 + 7200)
    assert restored.problem is not None and "saved_s is 79200 s in the future" in restored.problem
    # A simulation's clock runs ahead of the wall: a larger skew takes it.
    save_learned(tmp_path, SHA, {"disp_z_um": taught()}, now_s=1.7e9 + 86400)
    assert restore_learners(tmp_path, SHA, SETUPS, now_s=1.7e9, skew_s=14 * 86400).restored
