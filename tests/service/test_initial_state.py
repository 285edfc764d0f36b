"""How the daemon starts a model without a saved state: steady state from the model's thermal zero."""

from __future__ import annotations

import pytest
from structlog.testing import capture_logs

from compd.files.modelfile import parse_model
from compd.service.compensator import Counters
from compd.service.slots import ModelSlot, ModelSlots

#: A first-order lag of static gain 2 um/degC on the spindle temperature, at 1 s.
MODEL = """\
schema: compd.model/1
name: lag
sample_time_s: 1.0
outputs:
  disp_z_um:
    submodels:
      - name: spindle
        effect: spindle bearings
        input: {{signal: T_spindle_degC, reference: {reference}}}
        tf: {{form: discrete, power_order: ascending, nk: 1, num: [0.2], den: [1.0, -0.9]}}
"""


def first_output(reference: str, spindle_degC: float) -> tuple[float, str | None, list[dict]]:
    model_file = parse_model(MODEL.format(reference=reference))
    slot = ModelSlot(model_file, model_file.compile(), 0.0)
    slots = ModelSlots(slot, ["T_spindle_degC"], Counters())
    with capture_logs() as logs:
        slots.step(0.0, {"T_spindle_degC": spindle_degC})
    return slot.output("disp_z_um"), slot.initialised, logs


def test_a_model_with_a_thermal_zero_starts_warm_at_the_drift_it_predicts_and_says_so() -> None:
    """Without a saved state, a model whose reference is 20 degC read at 30 degC outputs 2 x 10 um at once."""
    output_um, initialised, logs = first_output("20.0", 30.0)
    assert output_um == pytest.approx(20.0)
    assert initialised is not None and "thermal zero" in initialised
    assert [e["how"] for e in logs if e["event"] == "initial state"] == [initialised]


def test_a_model_with_value_at_start_references_starts_at_zero_and_says_what_it_misses() -> None:
    """An older model file ('reference: start') starts at 0 and says the earlier drift is not compensated."""
    output_um, initialised, _ = first_output("start", 30.0)
    assert output_um == 0.0
    assert initialised is not None and "not compensated" in initialised
