"""State persistence: atomic files, the resume policy, model installation."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np
import pytest
from structlog.testing import capture_logs

from compd.errors import CompdError
from compd.files.modelfile import load_model
from compd.files.yamlplace import resolve_path
from compd.model.compiled import ModelState
from compd.service.loop.clock import VirtualClock
from compd.service.store.state import (
    STATE_FILE,
    SavedState,
    StateError,
    install_model,
    install_sidecars,
    installed_model,
    load_state,
    resume_decision,
    save_state,
)

from .daemon_setup import run, write_config

MODEL = resolve_path("bundled:example_gated_arx.yaml", Path("."))


@pytest.fixture(scope="module")
def model():
    model_file = load_model(MODEL)
    return model_file, model_file.compile()


def saved_for(model, *, sha256=None, saved_at=1000.0) -> SavedState:
    model_file, compiled = model
    state = compiled.steady_state(
        {"T_spindle_degC": 25.0, "T_shopfloor_degC": 20.0, "spindle_speed_rpm": 0.0}
    )
    return SavedState(sha256 or model_file.sha256, compiled.name, saved_at, state, {"Y": -1.5}, 42)


def test_round_trip(tmp_path, model):
    """A saved state loads back equal, model state to the last bit."""
    saved = saved_for(model)
    save_state(tmp_path, saved)
    loaded = load_state(tmp_path)
    assert loaded is not None
    np.testing.assert_array_equal(loaded.model_state.z, saved.model_state.z)
    np.testing.assert_array_equal(loaded.model_state.reference, saved.model_state.reference)
    assert (loaded.offsets_um, loaded.ticks, loaded.model_sha256) == (
        {"Y": -1.5},
        42,
        saved.model_sha256,
    )


def test_save_leaves_no_temporary_files(tmp_path, model):
    """Saving twice leaves exactly one state file and no temporary file."""
    save_state(tmp_path, saved_for(model))
    save_state(tmp_path, saved_for(model, saved_at=2000.0))
    assert [p.name for p in tmp_path.iterdir()] == [STATE_FILE]


def test_missing_and_malformed_state(tmp_path):
    """No file means no state; a malformed file is a StateError naming what is wrong."""
    assert load_state(tmp_path) is None
    (tmp_path / STATE_FILE).write_text(json.dumps({"format": "compd.state/1", "model_sha256": "x"}))
    with pytest.raises(StateError, match="malformed"):
        load_state(tmp_path)


@pytest.mark.parametrize(
    ("sha256", "now", "resume", "reason"),
    [
        (None, 1500.0, True, "500 s old"),
        ("0" * 64, 1500.0, False, "belongs to model 000000000000"),
        (None, 1000.0 + 901.0, False, "901 s old (limit 900 s)"),
        (None, 900.0, False, "100 s in the future"),
    ],
    ids=["fresh", "other-model", "too-old", "from-the-future"],
)
def test_resume_policy(model, sha256, now, resume, reason):
    """Resume only this model's state, younger than resume_max_age_s (and not from the future)."""
    decision = resume_decision(
        saved_for(model, sha256=sha256), model[0].sha256, model[1], now, 900.0
    )
    assert decision.resume is resume and reason in decision.reason


def test_a_state_file_that_is_not_text_is_a_state_error(tmp_path):
    """Bytes that are not UTF-8 (a corrupted card) are a StateError, so the daemon starts without them."""
    (tmp_path / STATE_FILE).write_bytes(b"\x80\xff{")
    with pytest.raises(StateError, match="not text"):
        load_state(tmp_path)


def test_a_state_file_nested_too_deeply_is_a_state_error(tmp_path):
    """A state file of 1M "[" (deeper than Python's JSON parser recurses) is a StateError, not a RecursionError."""
    (tmp_path / STATE_FILE).write_text("[" * 1_000_000)
    with pytest.raises(StateError, match="nested too deeply"):
        load_state(tmp_path)


@pytest.mark.parametrize("offset_um", [140.0, -50.5, 1e9, float("nan"), float("inf")])
def test_a_saved_offset_beyond_its_clamp_is_not_resumed(model, offset_um):
    """A saved offset that is not finite or lies beyond the axis's clamp makes the state unusable."""
    saved = saved_for(model)
    saved = SavedState(
        saved.model_sha256, saved.model_name, 1000.0, saved.model_state, {"Y": offset_um}, 42
    )
    decision = resume_decision(
        saved, model[0].sha256, model[1], 1500.0, 900.0, max_offsets_um={"Y": 50.0}
    )
    assert not decision.resume and "beyond ±50 um" in decision.reason
    fine = resume_decision(
        saved_for(model), model[0].sha256, model[1], 1500.0, 900.0, max_offsets_um={"Y": 50.0}
    )
    assert fine.resume


def test_install_model_points_current_at_the_copy(tmp_path):
    """An installed model is stored under its sha256 and becomes the current one."""
    assert installed_model(tmp_path) is None
    installed = install_model(tmp_path, MODEL)
    assert installed.name == f"{load_model(MODEL).sha256}.yaml"
    assert installed_model(tmp_path) == installed
    assert installed.read_bytes() == MODEL.read_bytes()


SIMULATED = resolve_path("bundled:simulated_model.yaml", Path("."))


@pytest.fixture(scope="module")
def ranged():
    """The simulated machine's model: its file records the calibration's input ranges."""
    model_file = load_model(SIMULATED)
    calibration = model_file.doc.provenance.calibration
    assert calibration is not None and "T_spindle_degC" in calibration.ranges
    return model_file, model_file.compile(), calibration.ranges


def _with_state(saved: SavedState, z=None, reference=None) -> SavedState:
    state = saved.model_state
    changed = ModelState(
        state.z if z is None else z, state.reference if reference is None else reference
    )
    return SavedState(saved.model_sha256, saved.model_name, saved.saved_at_unix_s, changed, {}, 1)


@pytest.mark.parametrize(
    ("where", "value", "reason"),
    [
        ("z", 1e300, "z[0] of disp_z_um/"),
        ("z", 1e5, "z[0] of disp_z_um/"),
        ("reference", 1e300, "input reference of disp_z_um/"),
        ("reference", -400.0, "input reference of disp_z_um/"),
    ],
)
def test_a_model_state_the_model_cannot_reach_is_not_resumed(ranged, where, value, reason):
    """A state beyond what the calibration's (widened) input ranges can drive the model to is refused, named."""
    model_file, compiled, ranges = ranged
    good = compiled.steady_state(
        {"T_spindle_degC": 30.0, "T_headstock_degC": 28.0, "T_column_front_degC": 23.0,
         "T_ambient_degC": 20.0}
    )  # fmt: skip
    saved = SavedState(model_file.sha256, compiled.name, 1000.0, good, {}, 1)
    decide = functools.partial(
        resume_decision, now_unix_s=1500.0, max_age_s=900.0, input_ranges=ranges
    )
    assert decide(saved, model_file.sha256, compiled).resume
    array = getattr(good, where).copy()
    array.flat[0] = value
    bogus = _with_state(saved, **{where: array})
    decision = decide(bogus, model_file.sha256, compiled)
    assert not decision.resume
    assert reason in decision.reason and "not a state this model produced" in decision.reason


def test_a_model_state_of_1e300_is_refused_without_calibration_ranges(model):
    """A model file without recorded ranges still refuses 1e300 (the generous unranged bound)."""
    saved = saved_for(model)
    bogus = _with_state(saved, z=np.full_like(saved.model_state.z, 1e300))
    decision = resume_decision(bogus, model[0].sha256, model[1], 1500.0, 900.0)
    assert not decision.resume and "not a state this model produced" in decision.reason
    assert resume_decision(saved, model[0].sha256, model[1], 1500.0, 900.0).resume


def test_a_daemon_with_a_1e300_state_file_starts_fresh_and_its_offsets_stay_small(tmp_path):
    """The state file's model_state at 1e300: not resumed, the offsets start at zero, never near the clamp."""
    config = write_config(tmp_path, {"drivers": {"machine": {"settings": {"start_s": 7200}}}})
    run(config, 10.0)  # saves its state at shutdown
    state = config.state_dir / STATE_FILE
    saved = json.loads(state.read_text())
    saved["model_state"]["z"] = [[1e300] * len(row) for row in saved["model_state"]["z"]]
    state.write_text(json.dumps(saved))
    clock = VirtualClock(wall0_unix_s=saved["saved_at_unix_s"] + 1.0)
    second, records = run(config, 20.0, clock=clock)
    assert not second.resumed
    clamp_um = config.doc.outputs["Y"].max_offset_um
    assert abs(records[0].offsets_um["Y"]) < 1e-9
    assert max(abs(r.offsets_um["Y"]) for r in records) < clamp_um / 2


def _state_text(data: dict, **replace: str) -> str:
    """The state ``data`` as JSON, with the values of ``replace``'s keys written as given."""
    data = dict(data)
    for key in replace:
        data[key] = f"@{key}@"
    text = json.dumps(data)
    for key, value in replace.items():
        text = text.replace(f'"@{key}@"', value)
    return text


@pytest.mark.parametrize(
    ("replace", "reason"),
    [
        ({"ticks": "Infinity"}, "ticks is inf, not a finite number"),
        ({"ticks": "1e400"}, "ticks is inf, not a finite number"),
        ({"ticks": "-Infinity"}, "ticks is -inf, not a finite number"),
        ({"ticks": "1" * 5000}, "ticks is an integer of 5000 digits"),
        ({"ticks": "-1"}, "ticks = -1 is beyond [0, 9.0072e+15]"),
        ({"ticks": "2.5"}, "ticks = 2.5 is not a whole number"),
        ({"saved_at_unix_s": "NaN"}, "saved_at_unix_s is nan, not a finite number"),
        ({"saved_at_unix_s": "1e300"}, "saved_at_unix_s = 1e+300 is beyond [0, 1e+11]"),
        ({"saved_real_unix_s": "-5"}, "saved_real_unix_s = -5 is beyond [0, 1e+11]"),
        ({"offsets_um": '{"Y": NaN}'}, "offsets_um.Y is nan, not a finite number"),
        ({"offsets_um": '{"Y": "1"}'}, "offsets_um.Y is '1', not a number"),
        ({"model_state": '{"z": [[NaN]], "reference": [0]}'}, "model_state holds NaN or inf"),
        ({"model_state": '{"z": [[1' + "0" * 400 + ']], "reference": [0]}'}, "NaN or infinity"),
    ],
)
def test_a_number_that_is_not_finite_or_out_of_range_is_a_state_error(
    tmp_path, model, replace, reason
):
    """Infinity, NaN, 1e400, 5,000 digits or a value out of range in a state file: a StateError naming the key."""
    (tmp_path / STATE_FILE).write_text(_state_text(saved_for(model).to_dict(), **replace))
    with pytest.raises(StateError) as info:
        load_state(tmp_path)
    assert reason in str(info.value)


def test_a_state_stamped_nan_is_not_resumed(model):
    """A state whose time is NaN (built in memory, not read) is never resumed: NaN passes no age check."""
    saved = saved_for(model, saved_at=float("nan"))
    decision = resume_decision(saved, model[0].sha256, model[1], 1500.0, 900.0)
    assert not decision.resume and "not a finite number" in decision.reason


@pytest.mark.parametrize(
    "replace",
    [{"ticks": "Infinity"}, {"ticks": "9" * 5000}, {"saved_at_unix_s": "NaN"}],
    ids=["infinity", "5000-digits", "nan-time"],
)
def test_a_daemon_with_a_corrupt_state_file_sets_it_aside_and_starts(tmp_path, replace):
    """The file is renamed state.json.corrupt-<time> (kept), one ERROR names it; the daemon starts afresh."""
    config = write_config(tmp_path)
    run(config, 5.0)  # a good state, to corrupt
    state = config.state_dir / STATE_FILE
    data = json.loads(state.read_text())
    corrupt = _state_text(data, **replace)
    state.write_text(corrupt)
    clock = VirtualClock(wall0_unix_s=data["saved_at_unix_s"] + 1.0)
    with capture_logs() as logs:
        service, records = run(config, 5.0, clock=clock)
    assert not service.resumed and len(records) == 6
    (error,) = [e for e in logs if e["log_level"] == "error"]
    (aside,) = config.state_dir.glob(f"{STATE_FILE}.corrupt-*")
    assert error["event"] == "saved state cannot be read: set aside; starting without it"
    assert error["file"] == str(state) and error["set_aside_as"] == str(aside)
    assert next(iter(replace)) in error["reason"]
    assert aside.read_text() == corrupt, "kept as it was"
    assert load_state(config.state_dir) is not None, "a new state saved at shutdown"


def test_an_installed_models_forest_is_never_replaced_by_another_of_its_name(
    tmp_path: Path,
) -> None:
    """Forests go beside the installed models; another model's forest of the same name is refused, not
    overwritten (the model installed with it would no longer start); a name with a folder is refused."""
    assert install_sidecars(tmp_path, {"m.residual.npz": b"first"}) == [
        tmp_path / "models" / "m.residual.npz"
    ]
    assert install_sidecars(tmp_path, {"m.residual.npz": b"first"}) == []  # the same: kept
    with pytest.raises(CompdError, match="holds another installed model's forest"):
        install_sidecars(tmp_path, {"m.residual.npz": b"second"})
    assert (tmp_path / "models" / "m.residual.npz").read_bytes() == b"first"
    for name in ("../m.residual.npz", "m.yaml", "/etc/m.npz"):
        with pytest.raises(CompdError, match=r"a \.npz file name with no folder"):
            install_sidecars(tmp_path, {name: b"x"})
