"""`compd model check` refuses model files beyond the bounds naming file and place; it never crashes or hangs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from compd.files.modelfile import load_model
from compd.model.limits import (
    MAX_DELAY_SAMPLES,
    MAX_GAIN_UM_PER_UNIT,
    MAX_ORDER,
    MAX_STATES,
    MAX_SUBMODELS,
)
from tests.clirun import compd_result

from .test_modelfile import VALID


def check(path: Path) -> tuple[int, str]:
    """``compd model check PATH``: exit code and what it printed on stderr."""
    code, _, err = compd_result("model", "check", path)
    return code, err


NUM, DEN = "num: [0.0162, 10.74, 5.368]", "den: [0.002098, 2.379, 1.0]"
GATE = "gate: {signal: n_rpm, above: 0}"
DISCRETE = [("form: continuous", "form: discrete"), (NUM, "num: [1.0]"), (DEN, "den: [1.0, -0.5]")]

#: The files of the issue: edits of a valid file, and what the refusal must say.
HOSTILE = {
    "gain 1e308": ([(GATE, GATE + "\n        gain: 1e308")], "(gain 1e+308 x TF"),
    "coefficients 1e308": (
        [*DISCRETE, ("num: [1.0]", "num: [1e308, 1e308]")],
        "static gain inf",
    ),
    "nk 1e6": (
        [*DISCRETE, ("den: [1.0, -0.5]", "den: [1.0, -0.5]\n          nk: 1000000")],
        "less than or equal to 600",
    ),
    "nk 1e10": (
        [*DISCRETE, ("den: [1.0, -0.5]", "den: [1.0, -0.5]\n          nk: 1.0e+10")],
        "less than or equal to 600",
    ),
    "delay_s 1e15": ([(DEN, DEN + "\n          delay_s: 1.0e+15")], "delays up to 600 samples"),
    "order 3000": ([(DEN, "den: [" + ", ".join(["1.0e-4"] * 3000) + "]")], "at most 33 items"),
    "den 1e-300": ([(NUM, "num: [1.0]"), (DEN, "den: [1.0, 1.0e-300]")], "orders of magnitude"),
    "sample time 1e308": (
        [("sample_time_s: 1.0", "sample_time_s: 1.0e+308")],
        "less than or equal to 3600",
    ),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_model_files_are_refused_by_check(case: str, tmp_path: Path) -> None:
    """Each file the issue found passing `check` (or blowing up) exits 2 naming the file, the place and the bound."""
    edits, expected = HOSTILE[case]
    text = VALID
    for old, new in edits:
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "model.yaml"
    path.write_text(text)
    code, err = check(path)
    assert code == 2, err
    assert err.startswith(f"error: {path}: ") or f"{path}: " in err
    assert "outputs.disp_z_um.submodels[0]" in err or "line " in err
    assert expected in err


def _tf(draw: Any) -> dict[str, Any]:
    form = draw(st.sampled_from(["discrete", "continuous"]))
    coefficient = st.one_of(
        st.floats(-10, 10, allow_nan=False),
        st.floats(allow_nan=False, allow_infinity=False),
        st.sampled_from([0.0, 1e-300, 1e300, -1e308]),
    )
    size = st.integers(1, MAX_ORDER + 8)
    tf: dict[str, Any] = {
        "form": form,
        "power_order": draw(st.sampled_from(["ascending", "descending"])),
        "num": draw(st.lists(coefficient, min_size=1, max_size=draw(size))),
        "den": [1.0, *draw(st.lists(coefficient, max_size=draw(size)))],
    }
    if form == "discrete" and draw(st.booleans()):
        tf["nk"] = draw(st.integers(0, 10**12))
    if form == "continuous" and draw(st.booleans()):
        tf["delay_s"] = draw(st.sampled_from([0.0, 1.0, 2.0, 600.0, 601.0, 1e15, 0.5]))
    return tf


@st.composite
def model_files(draw: Any) -> dict[str, Any]:
    """Model documents within and beyond the limits: orders, delays, gains, sub-model counts, sample times."""
    count = draw(st.one_of(st.integers(1, 3), st.integers(MAX_SUBMODELS - 1, MAX_SUBMODELS + 2)))
    gain = st.one_of(st.floats(-5, 5), st.sampled_from([1e5, 2e6, 1e308, -1e308, 0.0]))
    submodels = [
        {
            "name": f"s{i}",
            "effect": "heat",
            "input": {"signal": "T"},
            "tf": _tf(draw)
            if i < 3
            else {"form": "discrete", "power_order": "ascending", "num": [0.5], "den": [1.0, -0.5]},
            "gain": draw(gain),
        }
        for i in range(count)
    ]
    return {
        "schema": "compd.model/1",
        "name": "random",
        "sample_time_s": draw(st.sampled_from([1.0, 0.5, 2.0, 3600.0, 1e308, 1e-300])),
        "outputs": {"disp_z_um": {"submodels": submodels}},
    }


@settings(
    max_examples=80,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(doc=model_files())
def test_random_model_files_compile_within_the_limits_or_are_refused_naming_the_place(
    doc: dict[str, Any], tmp_path: Path
) -> None:
    """`model check` on a random file either accepts a model within every bound or exits 2 naming file and place."""
    path = tmp_path / "random.yaml"
    path.write_text(yaml.safe_dump(doc))
    code, err = check(path)  # any exception but a CompdError escapes main() and fails the test
    if code != 0:
        assert code == 2 and f"{path}: " in err, err
        assert "outputs.disp_z_um" in err or "line " in err or "sample time" in err, err
        return
    compiled = load_model(path).compile()
    assert compiled.n_submodels <= MAX_SUBMODELS
    assert compiled.n_submodels * (compiled.n_states + 1) <= MAX_STATES
    assert all(tf.nk <= MAX_DELAY_SAMPLES and tf.order <= MAX_ORDER for tf in compiled.discrete)
    gains = np.array([tf.static_gain() for tf in compiled.discrete]) * compiled.gain
    assert np.all(np.isfinite(gains)) and np.all(np.abs(gains) <= MAX_GAIN_UM_PER_UNIT)
    assert np.all(np.isfinite(compiled.b)) and np.all(np.isfinite(compiled.a))
