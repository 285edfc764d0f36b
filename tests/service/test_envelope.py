"""The offset's envelope: a target at the clamp or beyond the calibration for envelope_after_s is a fault."""

from __future__ import annotations

import math

import pytest
from pydantic import ValidationError

from compd.service.config.docs import SafetyDoc
from compd.service.loop.envelope import Envelope, EnvelopeSettings, EnvelopeWatch
from compd.service.loop.safety import AxisLimits, AxisSafety, FaultMode

#: The bundled model's calibration: disp_z_um from -98.4 to +7.1 um; offsets are -1 x the output.
CALIBRATED_UM = (-98.381, 7.064)
SETTINGS = EnvelopeSettings(margin=0.25, after_s=300.0)


def watch(band: tuple[float, float] | None = CALIBRATED_UM) -> EnvelopeWatch:
    return EnvelopeWatch(SETTINGS, Envelope.of(150.0, -1.0, band, SETTINGS.margin))


def test_the_band_is_the_calibrated_output_range_times_sign_widened_by_the_margin():
    """Offsets (sign -1) are trusted from -(7.064 + m) to +(98.381 + m), m = 0.25 x the span."""
    margin_um = 0.25 * (7.064 + 98.381)
    band = Envelope.of(150.0, -1.0, CALIBRATED_UM, 0.25).band_um
    assert band == pytest.approx((-7.064 - margin_um, 98.381 + margin_um))
    assert Envelope.of(150.0, 1.0, CALIBRATED_UM, 0.25).band_um == pytest.approx(
        (-98.381 - margin_um, 7.064 + margin_um)
    )


def test_without_a_calibrated_range_or_a_margin_only_the_clamp_is_watched():
    """A model file that records no output range, or ``envelope_margin: null``, judges the clamp alone."""
    for envelope in (Envelope.of(150.0, -1.0, None, 0.25), Envelope.of(150.0, -1.0, (0, 1), None)):
        assert envelope.band_um is None
        assert envelope.outside(149.9) is None and envelope.outside(-149.9) is None
        assert envelope.outside(150.0) == envelope.outside(-151.0) == "at the clamp"


def test_a_target_inside_the_envelope_is_never_a_fault_however_long():
    """Eight hours inside the band, up to its edges: never outside, never faulted."""
    w = watch()
    low, high = w.envelope.band_um or (0.0, 0.0)
    for t_s in range(0, 28_800, 10):
        assert not w.judge(float(t_s), low if t_s % 20 else high)
        assert w.why is None and w.outside_s == 0.0 and w.sentence("Z") is None


def test_a_target_at_the_clamp_is_a_fault_after_envelope_after_s_and_ends_once_back_inside():
    """At the clamp for 299 s: said, not a fault; at 300 s a fault; one tick back inside ends it."""
    w = watch()
    for t_s in range(300):
        assert not w.judge(1000.0 + t_s, 163.2)
    assert w.why == "at the clamp" and w.outside_s == 299.0
    assert w.sentence("Z") == (
        "Z asks for the clamp: target +163.2 um, clamp ±150 um, for 4 min; a fault after 5 min"
    )
    assert w.judge(1300.0, 163.2) and w.faulted
    assert (w.sentence("Z") or "").endswith(": faulted, the offset follows safety.on_fault")
    assert not w.judge(1301.0, 40.0) and w.sentence("Z") is None


def test_beyond_the_calibration_counts_as_outside_and_an_interrupted_spell_starts_again():
    """A target inside the clamp but past the band faults too; a tick back inside resets the count."""
    w = watch()
    beyond_um = 130.0  # past 98.4 + 26.4 um, inside the 150 um clamp
    for t_s in range(200):
        w.judge(float(t_s), beyond_um)
    assert w.why == "beyond the calibration"
    assert "calibrated -33.4..+124.7 um" in (w.sentence("Z") or "")
    w.judge(200.0, 50.0)  # back inside for one tick
    for t_s in range(201, 500):
        assert not w.judge(float(t_s), beyond_um)
    assert w.judge(501.0, beyond_um)


def test_a_target_that_is_not_finite_is_not_judged_and_ends_a_spell():
    """A NaN target (a model starting or faulted: its own fault) is neither outside nor inside for long."""
    w = watch()
    for t_s in range(400):
        w.judge(float(t_s), 163.0)
    assert w.faulted
    assert not w.judge(400.0, math.nan) and w.why is None and not w.faulted


@pytest.mark.parametrize("on_fault", list(FaultMode))
def test_an_envelope_fault_freezes_the_axis_then_ramps_or_holds_as_on_fault_says(on_fault):
    """The stage treats an envelope fault as an input fault: frozen, then ramped to 0 (ramp) or held (freeze)."""
    stage = AxisSafety(
        AxisLimits(max_offset_um=150.0, max_rate_um_per_s=1.0),
        1.0,
        on_fault=on_fault,
        fault_ramp_after_s=60.0,
        offset_um=150.0,
        envelope=SETTINGS,
    )
    stage.calibrate(-1.0, CALIBRATED_UM)
    outputs = [stage.step(170.0, float(t_s)) for t_s in range(400)]
    assert all(o.offset_um == 150.0 and not o.outside for o in outputs[:300])
    assert all(o.outside and o.frozen for o in outputs[300:])
    if on_fault is FaultMode.RAMP:  # frozen 60 s, then 1 um/s towards 0
        assert outputs[359].offset_um == 150.0
        assert outputs[-1].offset_um == pytest.approx(150.0 - (399 - 359))
        assert "ramps to 0 after 60 s" in (stage.watch.sentence("Z") or "")
    else:
        assert outputs[-1].offset_um == 150.0
        assert "held (safety.on_fault: freeze)" in (stage.watch.sentence("Z") or "")
    back = stage.step(60.0, 400.0)  # the target back inside: the fault ends, the stage slews on
    assert not back.outside and not back.frozen


def test_the_safety_section_documents_defaults_and_refuses_absurd_values():
    """``envelope_margin`` 0.25 and ``envelope_after_s`` 300 s by default; huge or negative values are refused."""
    doc = SafetyDoc()
    assert doc.envelope() == EnvelopeSettings(margin=0.25, after_s=300.0)
    assert SafetyDoc(envelope_margin=None).envelope().margin is None
    for bad in ({"envelope_margin": 1e308}, {"envelope_margin": -0.1}, {"envelope_after_s": 0}):
        with pytest.raises(ValidationError, match=next(iter(bad))):
            SafetyDoc(**bad)


def test_the_part_of_a_target_probes_measured_does_not_leave_the_calibration() -> None:
    """A long-nose machine drifts 1.7x the model: the probes' learned part is the machine's word,
    so only the model's own part is held to the calibrated range (the clamp to the whole)."""
    envelope = Envelope.of(150.0, 1.0, (-40.0, 0.0), 0.25)
    assert envelope.outside(-60.0) == "beyond the calibration"
    assert envelope.outside(-60.0, measured_um=-20.0) is None
    assert envelope.outside(-150.0, measured_um=-110.0) == "at the clamp"
