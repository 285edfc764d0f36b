"""Model files: the bundled examples load, and every malformed file is refused naming file, line and place."""

import hashlib
import textwrap
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.errors import ModelFileError
from compd.files.modelfile import load_model, parse_model
from compd.files.modelschema import unread_provenance_keys
from compd.files.modelwriter import provenance_lines
from tests.clirun import compd_result

CONFIG = Path(__file__).parent.parent / "config"

VALID = """\
schema: compd.model/1
name: t
sample_time_s: 1.0
signals:
  T_sp: {unit: degC}
  T_amb: {unit: degC}
  n_rpm: {unit: rpm}
outputs:
  disp_z_um:
    submodels:
      - name: heat
        effect: spindle
        input: {signal: T_sp, minus: T_amb}
        tf:
          form: continuous
          power_order: ascending
          num: [0.0162, 10.74, 5.368]
          den: [0.002098, 2.379, 1.0]
        gate: {signal: n_rpm, above: 0}
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "model.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def refusal(tmp_path: Path, text: str) -> str:
    with pytest.raises(ModelFileError) as info:
        load_model(write(tmp_path, text)).compile()
    message = str(info.value)
    assert message.startswith(str(tmp_path / "model.yaml"))
    return message


@pytest.mark.parametrize(
    "name", ["seed000_hmc_tf.yaml", "seed000_linear_regression.yaml", "example_gated_arx.yaml"]
)
def test_bundled_example_models_load_and_compile(name: str) -> None:
    """Every model shipped in config/ is valid and compiles at its own sample time."""
    compiled = load_model(CONFIG / name).compile()
    assert compiled.n_submodels >= 1
    assert all(np.all(np.abs(tf.poles()) < 1) for tf in compiled.discrete)


def test_seed000_model_carries_the_papers_coefficients() -> None:
    """The Horejs 2010 example holds E_z_heat (eq. 2) and E_ETVE (eq. 3) exactly as printed, ascending in s."""
    model = load_model(CONFIG / "seed000_hmc_tf.yaml").model
    heat, etve = model.outputs[0].submodels
    assert heat.tf.num == (0.0162, 10.74, 5.368)
    assert heat.tf.den == (0.002098, 2.379, 1.0)
    assert etve.tf.den == (4.02e-10, 1.181e-6, 0.001166, 0.01072, 1.0)


def test_valid_file_builds_input_gate_and_defaults(tmp_path: Path) -> None:
    """Input difference, reference 'start', output gate and gain 1 are read as written."""
    model_file = load_model(write(tmp_path, VALID))
    sub = model_file.model.outputs[0].submodels[0]
    assert (sub.input.signal, sub.input.minus, sub.input.reference) == ("T_sp", "T_amb", None)
    assert sub.gate is not None and sub.gate.above and sub.gate.target.value == "output"
    assert sub.gain == 1.0
    assert model_file.sha256 == hashlib.sha256((tmp_path / "model.yaml").read_bytes()).hexdigest()


def test_descending_power_order_is_reversed_explicitly(tmp_path: Path) -> None:
    """power_order: descending gives the same TF as the ascending list reversed."""
    text = (
        VALID.replace("ascending", "descending")
        .replace("[0.0162, 10.74, 5.368]", "[5.368, 10.74, 0.0162]")
        .replace("[0.002098, 2.379, 1.0]", "[1.0, 2.379, 0.002098]")
    )
    ascending = load_model(write(tmp_path, VALID)).compile()
    descending = load_model(write(tmp_path, text)).compile()
    assert_allclose(ascending.b, descending.b, rtol=1e-14)
    assert_allclose(ascending.a, descending.a, rtol=1e-14)


def test_unknown_key_names_line_and_place(tmp_path: Path) -> None:
    """A misspelt key is an error with its line and dotted place, never ignored."""
    message = refusal(tmp_path, VALID.replace("          den:", "          dens:"))
    assert "line 18 (outputs.disp_z_um.submodels[0].tf.dens)" in message
    assert "unknown key 'dens'" in message
    assert "Remove the key or fix its spelling" in message


def test_missing_power_order_is_refused(tmp_path: Path) -> None:
    """Nothing is guessed: a TF without power_order is an error naming the TF."""
    message = refusal(tmp_path, VALID.replace("          power_order: ascending\n", ""))
    assert "outputs.disp_z_um.submodels[0].tf.power_order" in message
    assert "required key 'power_order' is missing" in message


def test_wrong_type_is_refused_with_the_value(tmp_path: Path) -> None:
    """A coefficient that is not a number names the list element and the value."""
    message = refusal(tmp_path, VALID.replace("[0.002098, 2.379, 1.0]", "[0.002098, fast, 1.0]"))
    assert "outputs.disp_z_um.submodels[0].tf.den[1]" in message
    assert "'fast'" in message


def test_bad_choice_lists_the_allowed_values(tmp_path: Path) -> None:
    """power_order: up is refused and the message lists ascending and descending."""
    message = refusal(tmp_path, VALID.replace("power_order: ascending", "power_order: up"))
    assert "'ascending'" in message and "'descending'" in message


def test_missing_schema_is_refused_with_the_fix(tmp_path: Path) -> None:
    """A file without the schema line says which line to add."""
    message = refusal(tmp_path, VALID.replace("schema: compd.model/1\n", ""))
    assert "Start the file with 'schema: compd.model/1'" in message


def test_yaml_syntax_error_gives_line_and_column(tmp_path: Path) -> None:
    """Broken YAML names the line and column where parsing failed."""
    message = refusal(tmp_path, VALID.replace("num: [0.0162, 10.74, 5.368]", "num: [0.0162, 10.74"))
    assert "not valid YAML" in message and "line " in message


def test_non_causal_discrete_tf_names_its_place(tmp_path: Path) -> None:
    """A discrete TF with a0 = 0 is refused at load with the sub-model's tf place."""
    text = VALID.replace("form: continuous", "form: discrete").replace(
        "[0.002098, 2.379, 1.0]", "[0.0, 1.0]"
    )
    message = refusal(tmp_path, text)
    assert "outputs.disp_z_um.submodels[0].tf" in message and "non-causal" in message


def test_unstable_model_is_refused_at_compile_naming_file_and_sub_model(tmp_path: Path) -> None:
    """An unstable TF passes the schema but compile refuses it naming the file and sub-model."""
    text = VALID.replace("form: continuous", "form: discrete").replace(
        "[0.002098, 2.379, 1.0]", "[1.0, -1.5]"
    )
    message = refusal(tmp_path, text)
    assert "outputs.disp_z_um.submodels[0] (heat): unstable" in message


def test_undeclared_signal_is_refused(tmp_path: Path) -> None:
    """With a signals section, a typo in a signal name is caught at load."""
    message = refusal(tmp_path, VALID.replace("signal: T_sp,", "signal: T_spindel,"))
    assert "['T_spindel'] are not declared" in message and "T_sp" in message


def test_duplicate_sub_model_names_are_refused(tmp_path: Path) -> None:
    """Two sub-models of one output may not share a name (gains and reports address them by name)."""
    sub = VALID[VALID.index("      - name: heat") :]
    message = refusal(tmp_path, VALID + sub)
    assert "repeated: ['heat']" in message


def test_gate_needs_exactly_one_threshold(tmp_path: Path) -> None:
    """A gate with both 'above' and 'below' is ambiguous and refused."""
    message = refusal(tmp_path, VALID.replace("above: 0}", "above: 0, below: 5}"))
    assert "exactly one of 'above' or 'below'" in message


def test_nk_on_a_continuous_tf_is_refused(tmp_path: Path) -> None:
    """Delays are nk samples for discrete TFs and delay_s seconds for continuous ones."""
    message = refusal(
        tmp_path, VALID.replace("form: continuous", "form: continuous\n          nk: 2")
    )
    assert "use 'delay_s'" in message


def test_non_positive_sample_time_is_refused(tmp_path: Path) -> None:
    """sample_time_s must be > 0."""
    message = refusal(tmp_path, VALID.replace("sample_time_s: 1.0", "sample_time_s: 0"))
    assert "line 3 (sample_time_s)" in message and "greater than 0" in message


def test_output_unit_must_be_micrometres(tmp_path: Path) -> None:
    """Offsets are um throughout compd: another output unit is refused."""
    message = refusal(tmp_path, VALID.replace("  disp_z_um:\n", "  disp_z_um:\n    unit: mm\n"))
    assert "outputs.disp_z_um.unit" in message and "'um'" in message


def test_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    """A path that does not exist is reported, not a traceback."""
    with pytest.raises(ModelFileError, match="cannot read the file"):
        load_model(tmp_path / "nope.yaml")


def test_text_can_be_parsed_without_a_file() -> None:
    """parse_model validates text directly (used by tools that generate models)."""
    assert parse_model(VALID).model.name == "t"


IMPLAUSIBLE = textwrap.dedent(
    """\
    schema: compd.model/1
    name: eight-years
    sample_time_s: 15.0
    outputs:
      disp_um:
        submodels:
          - name: T16
            effect: a collinear sensor's balancing term
            input: {signal: T16}
            tf: {form: discrete, power_order: ascending, nk: 1, num: [-6.6e-3], den: [1.0, -0.99999994]}
    provenance:
      calibration:
        data: real.csv
        samples: 7712
        sample_time_s: 15.0
        ranges: {disp_um: [-71.0, 18.3], T16: [23.7, 29.8]}
    """
)


def test_a_model_implausible_for_its_calibration_is_refused_by_check(tmp_path: Path) -> None:
    """An 8-year, -1.1e5 um/K sub-model compiles, but the guard rails refuse it: the daemon never runs it."""
    model_file = load_model(write(tmp_path, IMPLAUSIBLE))
    model_file.compile()  # causal and stable: the old check said "ok"
    with pytest.raises(ModelFileError, match="implausible for its own calibration data") as refused:
        model_file.check_plausible()
    assert "T16" in str(refused.value) and "years" in str(refused.value)


def test_a_file_without_calibration_gets_only_the_checks_that_need_no_data(tmp_path: Path) -> None:
    """Without ranges or a record length there is nothing to judge gains and time constants against."""
    text = IMPLAUSIBLE[: IMPLAUSIBLE.index("provenance:")]
    assert load_model(write(tmp_path, text)).check_plausible() == []


NEWER_PROVENANCE = VALID + textwrap.dedent(
    """\
    provenance:
      method: lagbank
      selection_trace: [lagbank, mlr]
      cross_validation:
        output: disp_z_um
        folds: 4 operating cycles
        kept: lagbank
        nested_fit_percent: {lagbank: 81.0, mlr: 70.0}
        fold_trimmed_percent: {lagbank: 79.5}
      updates:
        - parent_sha256: abc
          data: run.csv
          probes: probes.csv
          characteristic: {data: run.csv, segment_signal: n_rpm, segments: 3, bounds_how: per segment}
    """
)


def test_provenance_keys_of_a_newer_compd_are_kept_not_refused(tmp_path: Path) -> None:
    """A file fitted by a newer compd records more about its fit; the model is the same, so it loads.

    Before, ``cross_validation.fold_median_percent`` (issue 20) made every older
    daemon refuse every newly fitted model.
    """
    model_file = load_model(write(tmp_path, NEWER_PROVENANCE))
    model_file.compile()
    provenance = model_file.doc.provenance
    assert provenance.cross_validation is not None
    assert provenance.cross_validation.expected_percent() == 81.0
    assert unread_provenance_keys(provenance) == [
        "provenance.selection_trace",
        "provenance.updates[0].characteristic.bounds_how",
        "provenance.cross_validation.fold_trimmed_percent",
    ]
    rewritten = "\n".join(provenance_lines(provenance))
    assert "selection_trace:" in rewritten and "fold_trimmed_percent:" in rewritten
    assert "bounds_how: per segment" in rewritten


def test_an_unknown_key_in_what_the_model_does_is_still_refused(tmp_path: Path) -> None:
    """Only the provenance is lenient: an unknown key beside a transfer function could change the offsets."""
    den = "          den: [0.002098, 2.379, 1.0]\n"
    text = VALID.replace(den, den + "          lead_s: 4\n")
    message = refusal(tmp_path, text)
    assert "lead_s" in message


def test_model_check_lists_the_provenance_keys_it_does_not_read(tmp_path: Path) -> None:
    code, out, _ = compd_result("model", "check", write(tmp_path, NEWER_PROVENANCE))
    assert code == 0
    assert "does not read" in out and "provenance.cross_validation.fold_trimmed_percent" in out


def test_a_count_beyond_any_float_is_refused_not_an_overflow(tmp_path: Path) -> None:
    """A calibration of 10^400 samples is refused by its bound; it never reaches float arithmetic (OverflowError)."""
    text = (CONFIG / "simulated_model.yaml").read_text()
    assert "samples: 8641" in text
    head, _, tail = text.rpartition("samples: 8641")  # the provenance's, after probe_prior's
    message = refusal(tmp_path, head + "samples: 1" + "0" * 400 + tail)
    assert "(provenance.calibration.samples): Input should be less than or equal to" in message


def test_the_output_range_is_the_calibration_s_else_the_probe_prior_s_peak_else_unknown():
    """The envelope's source: ``calibration.ranges`` of the output, else ``±output_peak_um``, else None (old files)."""
    bundled = load_model(CONFIG / "simulated_model.yaml")
    assert bundled.output_range("disp_z_um") == (-98.381, 7.064)
    assert (
        parse_model(VALID).output_range("disp_z_um") is None
    )  # no calibration record: the clamp only
    doc = bundled.doc
    without_ranges = doc.model_copy(
        update={
            "provenance": doc.provenance.model_copy(
                update={"calibration": doc.provenance.calibration.model_copy(update={"ranges": {}})}
            )
        }
    )
    peak_um = doc.probe_prior["disp_z_um"].output_peak_um
    assert replace(bundled, doc=without_ranges).output_range("disp_z_um") == (-peak_um, peak_um)
