"""compare says when a record starts mid-transient: equilibrium at its first sample is unfair to a model with state."""

import textwrap
from pathlib import Path

import numpy as np
import pandas as pd

from compd.files.data import load_data
from compd.files.modelfile import parse_model
from compd.model.compiled import ModelState
from compd.model.run import simulate
from compd.toolkit.evaluate import evaluate, mid_transient_note, signal_matrix
from tests.clirun import compd_result

SAMPLE_S = 15.0


def two_lags(dynamic: bool = True) -> str:
    """4 um/degC of T1 through a 3 h lag and -2 um/degC of T2 through 10 min (or both at once)."""
    slow, fast = ("[1.0, 10800.0]", "[1.0, 600.0]") if dynamic else ("[1.0]", "[1.0]")
    return textwrap.dedent(
        f"""\
        schema: compd.model/1
        name: lags
        sample_time_s: {SAMPLE_S}
        outputs:
          disp_um:
            submodels:
              - name: slow
                effect: column
                input: {{signal: T1}}
                tf: {{form: continuous, power_order: ascending, num: [4.0], den: {slow}}}
              - name: fast
                effect: spindle
                input: {{signal: T2}}
                tf: {{form: continuous, power_order: ascending, num: [-2.0], den: {fast}}}
        """
    )


def record(tmp_path: Path, heat_held_degc: float) -> Path:
    """4 h at 15 s, the displacement as the model makes it with ``heat_held_degc`` still in its slow part.

    Non-zero: the slow part still holds heat from before the file began, as in
    a file split off a running log; zero: the machine was in equilibrium.
    """
    n = 4 * 240
    rng = np.random.default_rng(0)
    frame = pd.DataFrame(
        {
            "time_s": np.arange(n) * SAMPLE_S,
            "T1": 20.0 + rng.normal(0.0, 0.01, n),
            "T2": 20.0 + np.linspace(0.0, 1.0, n),
            "disp_um": np.zeros(n),
        }
    )
    path = tmp_path / "split.csv"
    frame.to_csv(path, index=False)
    evaluation = evaluate(parse_model(two_lags()), load_data(path))
    compiled = evaluation.compiled
    signals = signal_matrix(compiled, evaluation.data)
    steady = compiled.steady_state(signals[0])
    z = steady.z.copy()
    z[0, 0] += heat_held_degc
    held = simulate(compiled, signals, ModelState(z, steady.reference, steady.residual))
    frame["disp_um"] = held.output(compiled, "disp_um")
    frame.to_csv(path, index=False)
    return path


def test_a_model_judged_on_a_file_that_starts_mid_transient_gets_the_note(tmp_path: Path) -> None:
    evaluation = evaluate(parse_model(two_lags()), load_data(record(tmp_path, 6.0)))
    note = mid_transient_note(evaluation)
    assert note is not None
    assert "mid-transient" in note and "--init estimate --from 1:00" in note


def test_a_record_that_starts_in_equilibrium_gets_no_note(tmp_path: Path) -> None:
    evaluation = evaluate(parse_model(two_lags()), load_data(record(tmp_path, 0.0)))
    assert mid_transient_note(evaluation) is None


def test_a_static_model_has_no_state_to_start_wrong(tmp_path: Path) -> None:
    evaluation = evaluate(parse_model(two_lags(dynamic=False)), load_data(record(tmp_path, 6.0)))
    assert mid_transient_note(evaluation) is None


def test_compare_prints_the_note_and_not_when_judged_from_the_estimated_state(
    tmp_path: Path,
) -> None:
    model = tmp_path / "lags.yaml"
    model.write_text(two_lags())
    data = record(tmp_path, 6.0)
    code, _, err = compd_result("compare", model, data)
    assert code == 0 and "mid-transient" in err
    code, _, err = compd_result("compare", model, data, "--init", "estimate")
    assert code == 0 and "mid-transient" not in err
