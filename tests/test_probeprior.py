"""The model file's ``probe_prior`` block: read back as written, a wrong shape refused, absent -> the default."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from compd.errors import ModelFileError
from compd.files.modelfile import parse_model
from compd.files.modelwriter import model_to_yaml
from compd.files.probeprior import output_prior, probe_prior_doc
from compd.model import ContinuousTF, InputSpec, Model, Output, SubModel
from compd.model.updateprior import BIAS, calibration_prior


def _model() -> Model:
    tf = ContinuousTF((2.0,), (600.0, 1.0))
    subs = (SubModel("spindle", "spindle", InputSpec("T_spindle_degC"), tf),)
    return Model("m", 1.0, (Output("disp_z_um", subs),))


def _prior():
    rng = np.random.default_rng(0)
    c = np.cumsum(rng.normal(size=(500, 1)), axis=0)
    return calibration_prior(("spindle", BIAS), c, rng.normal(0, 0.3, 500))


def test_the_block_round_trips() -> None:
    """What fit writes is what the update reads: names, covariance (10 digits), sigma, n_eff, peak."""
    prior = _prior()
    text = model_to_yaml(_model(), probe_prior={"disp_z_um": probe_prior_doc(prior)})
    read = output_prior(parse_model(text), "disp_z_um", ("spindle",))
    assert read.note is None
    assert read.prior.names == prior.names
    np.testing.assert_allclose(read.prior.covariance, prior.covariance, rtol=1e-9)
    assert read.prior.effective_samples == pytest.approx(prior.effective_samples)
    assert read.prior.output_peak_um == pytest.approx(prior.output_peak_um)


def test_a_covariance_of_the_wrong_shape_is_refused() -> None:
    """A 2-parameter block with a 1 x 1 covariance is a model-file error naming the block."""
    text = model_to_yaml(_model(), probe_prior={"disp_z_um": probe_prior_doc(_prior())})
    start = text.index("    covariance:")
    broken = text[:start] + "    covariance:\n      - [1.0]\n"
    with pytest.raises(ModelFileError, match="probe_prior"):
        parse_model(broken)


def test_without_the_block_the_default_and_a_note() -> None:
    """No block: gains 1 +- 0.3, bias 0 +- 2 um (1 um: no calibration RMS recorded), and a note saying so."""
    read = output_prior(parse_model(model_to_yaml(_model())), "disp_z_um", ("spindle",))
    assert read.prior.source == "default"
    np.testing.assert_allclose(np.sqrt(np.diag(read.prior.covariance)), [0.3, 2.0])
    assert read.note is not None and "conservative default" in read.note


def test_the_transient_variances_round_trip_and_a_negative_one_is_refused() -> None:
    """Per probe interval (s) the residue's transient variance (um^2), read back as written; a
    negative variance is a model-file error naming the block."""
    prior = dataclasses.replace(_prior(), transient_um2=((900.0, 0.25), (7200.0, 1.5)))
    text = model_to_yaml(_model(), probe_prior={"disp_z_um": probe_prior_doc(prior)})
    assert "transient_variance_um2:" in text
    read = output_prior(parse_model(text), "disp_z_um", ("spindle",))
    assert read.prior.transient_um2 == ((900.0, 0.25), (7200.0, 1.5))
    assert read.prior.transient_variance_um2(7200.0) == pytest.approx(1.5)
    with pytest.raises(ModelFileError, match="probe_prior"):
        parse_model(text.replace("7200.0: 1.5", "7200.0: -1.5"))
