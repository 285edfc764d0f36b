"""The reachable-state bound (compd.model.reach): sound for every input in range, and it names what is beyond."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from compd.errors import ModelError
from compd.files.modelfile import load_model
from compd.files.yamlplace import resolve_path
from compd.model.reach import INPUT_MARGIN, check_reachable
from compd.model.run import TickRunner

MODEL = load_model(resolve_path("bundled:simulated_model.yaml", Path(".")))
COMPILED = MODEL.compile()
assert MODEL.doc.provenance.calibration is not None
RANGES = MODEL.doc.provenance.calibration.ranges


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), switch_every=st.integers(1, 200))
def test_every_state_the_model_reaches_from_inputs_in_range_is_accepted(seed, switch_every):
    """Inputs inside the calibration ranges (bang-bang: the worst kind) keep every state within the bound."""
    rng = np.random.default_rng(seed)
    lows = np.array([RANGES[s][0] for s in COMPILED.signals])
    highs = np.array([RANGES[s][1] for s in COMPILED.signals])
    start = rng.uniform(lows, highs)
    runner = TickRunner(COMPILED, COMPILED.steady_state(start))
    for k in range(2000):
        if k % switch_every == 0:
            values = np.where(rng.random(len(lows)) < 0.5, lows, highs)
        runner.step(dict(zip(COMPILED.signals, values, strict=True)))
    check_reachable(COMPILED, runner.state, RANGES)


def test_inputs_far_beyond_the_widened_ranges_reach_a_state_that_is_refused():
    """Inputs held far beyond the widened ranges drive the model to a state that is refused: the bound bites."""
    far = {s: RANGES[s][1] + (INPUT_MARGIN + 5) * 100 * (RANGES[s][1] - RANGES[s][0] + 1)
           for s in COMPILED.signals}  # fmt: skip
    near = {s: RANGES[s][0] for s in COMPILED.signals}
    runner = TickRunner(COMPILED, COMPILED.steady_state(near))
    for _ in range(5000):
        runner.step(far)
    with pytest.raises(ModelError, match="not a state this model produced"):
        check_reachable(COMPILED, runner.state, RANGES)
