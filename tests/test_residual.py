"""Residual-model files (Swiss-lathe paper): the YAML block, the sha256-checked .npz sidecar, and the fit's refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from compd.errors import DataFileError, ModelFileError
from compd.files.modelfile import load_model
from compd.files.modelwriter import model_to_yaml
from compd.model.compiled import compile_model
from compd.model.run import simulate
from compd.model.structure import InputSpec, Model, Output, SubModel
from compd.model.transfer import DiscreteTF
from compd.toolkit.residual import (
    check_door_signal,
    fit_residual,
    sidecar_path,
)
from tests.stacked import forest_beside

DT_S = 10.0


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> tuple[Path, Model]:
    """A stacked model fitted on a synthetic door residue, written as YAML plus sidecar."""
    folder = tmp_path_factory.mktemp("residual")
    door = (np.arange(2000) % 200 >= 150).astype(float)
    residue = -3.0 * door + np.random.default_rng(0).normal(0, 0.2, door.size)
    fit = fit_residual(residue, door, signal="door_open", sample_time_s=DT_S, trees=10, max_depth=6)
    assert fit.stacked.rms_um < 0.5 * fit.tf_alone.rms_um
    tf = DiscreteTF.from_coefficients([0.0, 0.1], [1.0, -0.9], 0)
    sub = SubModel("T_a", "temperature", InputSpec("T_a_degC"), tf)
    model = Model("stacked", DT_S, (Output("disp_z_um", (sub,), fit.residual),))
    path = folder / "model.yaml"
    doc = forest_beside(path, fit.residual, trees=10)
    signals = {"T_a_degC": "degC", "door_open": "-"}
    path.write_text(model_to_yaml(model, signals=signals, residuals={"disp_z_um": doc}))
    return path, model


def test_round_trip_keeps_the_forest(written) -> None:
    """A stacked model written and loaded again has the same forest arrays and simulates the same outputs."""
    path, model = written
    loaded = load_model(path)
    original = model.outputs[0].residual
    residual = loaded.model.outputs[0].residual
    assert residual is not None and original is not None
    assert residual.features == original.features
    for name in ("roots", "left", "right", "feature", "threshold", "value"):
        assert_array_equal(getattr(residual.forest, name), getattr(original.forest, name))
    door = (np.arange(500) % 90 > 60).astype(float)
    signals = np.column_stack([20 + 0.01 * np.arange(500), door])
    before, after = compile_model(model), loaded.compile()
    assert_allclose(
        simulate(after, signals, after.steady_state(signals[0])).outputs,
        simulate(before, signals, before.steady_state(signals[0])).outputs,
    )


def test_changed_sidecar_is_refused(written, tmp_path) -> None:
    """A sidecar whose sha256 differs from the one the YAML names is a ModelFileError naming the file and the fix."""
    path, _ = written
    copy = tmp_path / "model.yaml"
    copy.write_text(path.read_text())
    sidecar_path(copy).write_bytes(sidecar_path(path).read_bytes() + b"\0")
    with pytest.raises(ModelFileError, match=r"model\.residual\.npz.*another model") as info:
        load_model(copy)
    assert "refit" in str(info.value)


def test_missing_sidecar_is_refused(written, tmp_path) -> None:
    """A model file whose sidecar is absent is a ModelFileError naming the .npz it looked for."""
    path, _ = written
    copy = tmp_path / "model.yaml"
    copy.write_text(path.read_text())
    with pytest.raises(ModelFileError, match=r"model\.residual\.npz.*cannot be read"):
        load_model(copy)


@pytest.mark.parametrize("file", ["/etc/hostname", "../model.residual.npz", "sub/x.npz", ".."])
def test_a_sidecar_named_outside_the_model_files_folder_is_refused(written, tmp_path, file) -> None:
    """The sidecar is a file name beside the model file: a path elsewhere is refused at its line,
    before any file is read (a daemon parses models a client sends)."""
    path, _ = written
    copy = tmp_path / "model.yaml"
    copy.write_text(path.read_text().replace("file: model.residual.npz", f"file: {file!r}"))
    with pytest.raises(ModelFileError, match=r"residual\.file.*must be a file name beside"):
        load_model(copy)


def test_door_that_never_changes_is_refused() -> None:
    """Calibration data whose door signal never changes state cannot calibrate a door residual."""
    with pytest.raises(DataFileError, match=r"never changes state.*always shut"):
        check_door_signal("calib.csv", np.zeros(100), "door_open", 0.5)
    check_door_signal("calib.csv", np.r_[np.zeros(50), np.ones(5)], "door_open", 0.5)


def test_a_later_part_is_fitted_with_features_run_from_the_start() -> None:
    """With ``first_sample`` the residue before it is never read; the figures are those after it."""
    door = (np.arange(2000) % 200 >= 150).astype(float)
    residue = -3.0 * door + np.random.default_rng(0).normal(0, 0.2, door.size)
    spoiled = residue.copy()
    spoiled[:500] = 1e3
    fits = [
        fit_residual(r, door, signal="door_open", sample_time_s=DT_S, trees=5, first_sample=500)
        for r in (residue, spoiled)
    ]
    assert_array_equal(fits[0].residual.forest.value, fits[1].residual.forest.value)
    assert fits[1].tf_alone.rms_um == pytest.approx(float(np.sqrt(np.mean(residue[500:] ** 2))))
