"""Small model builders shared by the core's tests."""

from __future__ import annotations

from compd.model import DiscreteTF, Gate, GateTarget, InputSpec, Model, Output, SubModel


def first_order(gain: float, pole: float, nk: int = 1) -> DiscreteTF:
    """``gain * (1 - pole) z^-nk / (1 - pole z^-1)``: unit static gain times ``gain``."""
    return DiscreteTF.from_coefficients([gain * (1.0 - pole)], [1.0, -pole], nk=nk)


def single(
    tf: DiscreteTF, *, reference: float | None = 0.0, gate: Gate | None = None, gain: float = 1.0
) -> Model:
    """One output ``disp_z_um`` with one sub-model on signal ``T_degC``."""
    sub = SubModel("heat", "test effect", InputSpec("T_degC", reference=reference), tf, gain, gate)
    return Model("test", 1.0, (Output("disp_z_um", (sub,)),))


def gate_on(signal: str = "speed_rpm", target: GateTarget = GateTarget.OUTPUT) -> Gate:
    return Gate(signal, 0.0, True, target)
