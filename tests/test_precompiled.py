"""Model files carry their difference equations per loop period; the daemon steps them and converts nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from compd.errors import ModelFileError
from compd.files.equations import with_equations
from compd.files.modelfile import load_model, parse_model
from compd.files.modelwriter import model_to_yaml
from compd.model import DiscreteTF, InputSpec, Model, Output, SubModel, compile_model
from compd.model.precompiled import check_derived, tfs_sha256
from tests.acceptance.conftest import machine_doc
from tests.clirun import compd_result

CONFIG = Path(__file__).parents[1] / "config"
BUNDLED_MODELS = sorted(
    p.name for p in CONFIG.glob("*.yaml") if "schema: compd.model/1" in p.read_text()
)


def without_equations(path: Path, destination: Path) -> Path:
    """``path`` as a file written before the section existed."""
    destination.write_text(with_equations(path.read_text(), []))
    return destination


def discrete_model(sample_time_s: float, den: tuple[float, ...] = (1.0, -0.9)) -> Model:
    sub = SubModel(
        "heat",
        "spindle",
        InputSpec("T_degC", None, 20.0),
        DiscreteTF.from_coefficients([0.1], den, 1),
    )
    return Model("m", sample_time_s, (Output("disp_z_um", (sub,)),))


@pytest.mark.parametrize("name", BUNDLED_MODELS)
def test_every_bundled_model_runs_at_one_second_with_numpy_alone(name: str) -> None:
    """Each bundled model compiles at 1 s without converting, to the arrays the conversion gives."""
    model_file = load_model(CONFIG / name)
    assert 1.0 in model_file.runnable_periods_s()
    stepped = model_file.compile(1.0, convert=False)
    converted = compile_model(model_file.model, 1.0)
    np.testing.assert_allclose(stepped.b, converted.b, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(stepped.a, converted.a, rtol=1e-12, atol=1e-15)
    for stored in model_file.equations:
        check_derived(model_file.model, stored)


def test_a_file_that_needs_converting_is_refused_naming_the_command_that_precompiles_it(
    tmp_path: Path,
) -> None:
    """The bundled 10 s model without its equations: no run at 1 s, the fix names file and period."""
    old = without_equations(CONFIG / "simulated_model.yaml", tmp_path / "old.yaml")
    with pytest.raises(ModelFileError) as refused:
        load_model(old).compile(1.0, convert=False)
    text = str(refused.value)
    assert str(old) in text and "outputs.disp_z_um.submodels[0]" in text
    assert f"compd model compile {old} --period-s 1" in text
    assert "10 s to resample" in text and "runs as it is at: 10 s" in text


def test_a_file_of_before_still_compiles_in_the_toolkit_to_the_same_arrays(tmp_path: Path) -> None:
    """Old files load unchanged: the toolkit converts them, to what the precompiled file runs."""
    old = load_model(without_equations(CONFIG / "simulated_model.yaml", tmp_path / "old.yaml"))
    new = load_model(CONFIG / "simulated_model.yaml")
    assert old.equations == () and old.runnable_periods_s() == [10.0]
    np.testing.assert_array_equal(old.compile(1.0).b, new.compile(1.0, convert=False).b)


def test_check_config_says_what_compd_run_would_refuse(tmp_path: Path) -> None:
    """``compd check-config`` compiles as the daemon does: a model that needs converting is an error."""
    old = without_equations(CONFIG / "simulated_model.yaml", tmp_path / "old.yaml")
    config = tmp_path / "compd.yaml"
    config.write_text(yaml.safe_dump(machine_doc(tmp_path, old, simulation={"hours": 1})))
    status, _, err = compd_result("check-config", config)
    assert status == 2 and f"compd model compile {old} --period-s 1" in err


def test_a_tf_edited_after_its_equations_were_written_is_refused_on_reading() -> None:
    """Stale equations are never run: the file's line, the place, and the fix."""
    text = (CONFIG / "simulated_model.yaml").read_text()
    edited = text.replace("-5.153093192794746", "-5.15", 1)
    with pytest.raises(ModelFileError) as refused:
        parse_model(edited, "edited.yaml")
    message = str(refused.value)
    assert "difference_equations[0].tfs_sha256" in message and "line " in message
    assert "compd model compile edited.yaml" in message


def test_equations_must_name_the_model_s_sub_models_once_per_period() -> None:
    """A set naming other sub-models, or a second set at one period, is refused."""
    text = (CONFIG / "simulated_model.yaml").read_text()
    renamed = text.replace('        "T_ambient_degC": {nk:', '        "T_air_degC": {nk:')
    with pytest.raises(ModelFileError, match=r"difference_equations\[0\]\.outputs"):
        parse_model(renamed, "renamed.yaml")
    start = text.index("  - period_s: 1.0")
    end = text.index("# each input predicted")
    doubled = text[:end] + text[start:end] + text[end:]
    with pytest.raises(ModelFileError, match=r"a second set at 1 s"):
        parse_model(doubled, "doubled.yaml")


def test_model_check_refuses_equations_that_are_not_what_their_tf_gives(tmp_path: Path) -> None:
    """A set whose sha256 matches but whose numbers were changed by hand: ``compd model check`` says so."""
    text = (CONFIG / "simulated_model.yaml").read_text()
    forged = tmp_path / "forged.yaml"
    forged.write_text(text.replace("num: [0.0, -3.447653928388976", "num: [0.0, -3.4", 1))
    status, _, err = compd_result("model", "check", forged)
    assert status == 2 and "not what its TF gives" in err and "compd model compile" in err


def test_model_compile_writes_the_section_and_keeps_the_rest_of_the_file(tmp_path: Path) -> None:
    """Comments and keys as written; the periods asked and those carried; twice is once."""
    old = without_equations(CONFIG / "seed000_hmc_tf.yaml", tmp_path / "hmc.yaml")
    before = old.read_text()
    status, out, err = compd_result("model", "compile", old, "--period-s", 0.5)
    assert status == 0, err
    assert "difference equations at 0.5 s" in out and "sha256" in out
    status, _, err = compd_result("model", "compile", old, "--period-s", 1)
    assert status == 0, err
    written = old.read_text()
    assert with_equations(written, []) == before
    assert load_model(old).runnable_periods_s() == [0.5, 1.0]
    compd_result("model", "compile", old, "--period-s", 1)
    assert old.read_text() == written


def test_model_compile_names_a_period_the_model_cannot_be_brought_to(tmp_path: Path) -> None:
    """A pole on the negative real axis has no continuous equivalent: no equations at 1 s, and why."""
    path = tmp_path / "m.yaml"
    path.write_text(model_to_yaml(discrete_model(10.0, den=(1.0, 0.5))))
    assert load_model(path).equations == ()  # the writer leaves out what it cannot derive
    status, _, err = compd_result("model", "compile", path, "--period-s", 1)
    assert status == 2 and "cannot run at 1 s" in err and "negative real axis" in err


def test_model_compile_derives_anew_the_equations_of_a_tf_edited_after_they_were_written(
    tmp_path: Path,
) -> None:
    """Every reader refuses equations derived from other TFs, naming ``compd model compile``; that
    command itself takes them as what it writes anew, at the periods they were carried at."""
    path = tmp_path / "m.yaml"
    path.write_text(model_to_yaml(discrete_model(10.0)).replace("-0.9]", "-0.8]", 1))
    with pytest.raises(ModelFileError, match=r"derived from other TFs.*compd model compile"):
        load_model(path)
    status, out, err = compd_result("model", "compile", path)
    assert status == 0, err
    assert "were derived from other TFs" in out and "derived anew" in out
    assert [e.period_s for e in load_model(path).equations] == [1.0]


def test_a_written_model_carries_the_equations_its_periods_need() -> None:
    """10 s discrete: 1 s precompiled; 1 s discrete: none needed, it runs as it is."""
    at_10 = parse_model(model_to_yaml(discrete_model(10.0)), "m10.yaml")
    assert [e.period_s for e in at_10.equations] == [1.0]
    at_1 = parse_model(model_to_yaml(discrete_model(1.0)), "m1.yaml")
    assert at_1.equations == () and at_1.runnable_periods_s() == [1.0]


def test_the_tfs_digest_does_not_depend_on_how_the_file_spells_them() -> None:
    """Descending powers and ascending ones of the same TF are one set of equations."""
    text = (CONFIG / "seed000_hmc_tf.yaml").read_text()
    model = load_model(CONFIG / "seed000_hmc_tf.yaml").model
    doc = yaml.safe_load(text)
    for output in doc["outputs"].values():
        for sub in output["submodels"]:
            tf = sub["tf"]
            if tf["power_order"] == "ascending":
                tf["num"], tf["den"] = tf["num"][::-1], tf["den"][::-1]
                tf["power_order"] = "descending"
    respelt = parse_model(yaml.safe_dump(doc, sort_keys=False), "respelt.yaml")
    assert tfs_sha256(respelt.model) == tfs_sha256(model)
