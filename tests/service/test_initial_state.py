"""How the daemon starts a model without a saved state: steady state from the model's thermal zero."""

from __future__ import annotations

import pytest
from structlog.testing import capture_logs

from compd.files.modelfile import parse_model
from compd.service.loop.compensator import Counters
from compd.service.loop.slots import ModelSlot, ModelSlots

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


#: The same lag, and a second one of 1 um/degC on the shop air, with a zero that follows the air.
MODEL_AIR = """\
schema: compd.model/1
name: lag-air
sample_time_s: 1.0
ambient: {signal: T_ambient_degC, reference: 20.0, moves: [T_spindle_degC, T_ambient_degC]}
outputs:
  disp_z_um:
    submodels:
      - name: spindle
        effect: spindle bearings
        input: {signal: T_spindle_degC, reference: 22.0}
        tf: {form: discrete, power_order: ascending, nk: 1, num: [0.2], den: [1.0, -0.9]}
      - name: air
        effect: shop air
        input: {signal: T_ambient_degC, reference: 20.0}
        tf: {form: discrete, power_order: ascending, nk: 1, num: [0.1], den: [1.0, -0.9]}
"""


def first_output(
    reference: str, spindle_degC: float, text: str = MODEL, **more: float
) -> tuple[float, str | None, list[dict]]:
    model_file = parse_model(text.format(reference=reference) if text is MODEL else text)
    slot = ModelSlot(model_file, model_file.compile(), 0.0)
    values = {"T_spindle_degC": spindle_degC, **more}
    slots = ModelSlots(slot, list(values), Counters())
    with capture_logs() as logs:
        slots.step(0.0, values)
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


def test_the_thermal_zero_follows_the_shop_air() -> None:
    """The shop 1 degC warmer than at calibration, the spindle 6 degC above its reference: 2 x 5 um, the air 0."""
    output_um, initialised, _ = first_output("", 28.0, MODEL_AIR, T_ambient_degC=21.0)
    assert output_um == pytest.approx(10.0)
    assert initialised is not None and "thermal zero (moved with T_ambient_degC)" in initialised


def test_a_machine_that_reads_cold_starts_from_its_own_readings_and_says_so() -> None:
    """Every temperature within the cold band of its moved zero: today's readings are the zero, offsets 0."""
    output_um, initialised, _ = first_output("", 23.3, MODEL_AIR, T_ambient_degC=21.0)
    assert output_um == 0.0
    assert initialised is not None and "reads cold" in initialised


def test_a_shop_that_touches_off_warm_starts_from_zero_and_follows_the_drift_from_there() -> None:
    """``state.fresh_start: now``: read warm (30 degC, zero at 20) it outputs 0, then 2 um per degC of what follows."""
    model_file = parse_model(MODEL.format(reference="20.0"))
    slot = ModelSlot(model_file, model_file.compile(), 0.0)
    slots = ModelSlots(slot, ["T_spindle_degC"], Counters(), zero_now=True)
    with capture_logs() as logs:
        slots.step(0.0, {"T_spindle_degC": 30.0})
    assert slot.output("disp_z_um") == 0.0
    assert slot.initialised is not None and "state.fresh_start: now" in slot.initialised
    assert [e["how"] for e in logs if e["event"] == "initial state"] == [slot.initialised]
    for tick in range(1, 200):  # the spindle 1 degC warmer from now on: the lag settles at 2 um
        slots.step(float(tick), {"T_spindle_degC": 31.0})
    assert slot.output("disp_z_um") == pytest.approx(2.0, abs=1e-6)


def test_fresh_start_is_a_config_choice_and_thermal_zero_the_default(tmp_path) -> None:
    """The config key takes ``thermal_zero`` (default) or ``now``; anything else is refused naming it."""
    from compd.errors import ConfigFileError

    from .daemon_setup import write_config

    assert write_config(tmp_path).doc.state.fresh_start == "thermal_zero"
    assert write_config(tmp_path, {"state": {"fresh_start": "now"}}).doc.state.fresh_start == "now"
    with pytest.raises(ConfigFileError, match="fresh_start"):
        write_config(tmp_path, {"state": {"fresh_start": "cold"}})


@pytest.mark.parametrize("fresh_start", ["thermal_zero", "now"])
def test_the_daemon_starts_its_model_as_the_config_says(tmp_path, fresh_start: str) -> None:
    """``compd run`` without a state: the model's start follows ``state.fresh_start`` and the log says which."""
    from .daemon_setup import run, write_config

    config = write_config(tmp_path, {"state": {"fresh_start": fresh_start}})
    service, _ = run(config, 2.0)
    models = service.compensator.models
    assert models is not None and models.zero_now is (fresh_start == "now")
    initialised = models.active.initialised or ""
    assert ("state.fresh_start: now" in initialised) is (fresh_start == "now"), initialised
