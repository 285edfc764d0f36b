"""The structure of a compensation model: axis outputs as sums of gated, gained sub-models.

Horejs 2015 superposes one TF per physical effect; Post-process 2024 eq. 5/6 adds a gate
(``g_n = 1`` while the spindle turns) and post-process gains ``g1, g2``::

    disp_z = sum_i  gain_i * gate_i(k) * (P_i(k) - P_ref,i) * TF_i( input_i(k) )

where ``input_i`` is a signal, or the difference of two signals, taken as a
change from a reference (its value at start, or a fixed value). Pahk 2002
eq. 5 adds position-dependent feed-axis errors ``m1(T) * P + m2(T)``: a
sub-model with a ``position`` has its contribution multiplied by the axis
position minus a reference (its TF then gives a slope in um per mm, ``m1``,
as SINUMERIK's TEMP_COMP_SLOPE with its reference position); sub-models
without one (factor 1) give the offset ``m2``.

These are plain frozen values; the model file layer builds them, the
compiler turns them into flat arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from compd.model.residual import ResidualModel
from compd.model.transfer import ContinuousTF, DiscreteTF


class GateTarget(StrEnum):
    """Where a gate acts.

    ``OUTPUT`` (Post-process 2024 eq. 5 read literally): the TF always runs on its
    input and its *contribution* is switched; ``INPUT``: the TF's input is
    switched, so its contribution decays with the TF's own dynamics.
    """

    OUTPUT = "output"
    INPUT = "input"


@dataclass(frozen=True)
class InputSpec:
    """``signal - minus - reference``; ``reference=None`` means the value at start."""

    signal: str
    minus: str | None = None
    reference: float | None = None

    def describe(self) -> str:
        text = self.signal if self.minus is None else f"{self.signal} - {self.minus}"
        origin = "value at start" if self.reference is None else f"{self.reference:g}"
        return f"({text}) - {origin}"


@dataclass(frozen=True)
class Gate:
    """Active while ``signal > threshold`` (``above=True``) or ``signal < threshold``."""

    signal: str
    threshold: float = 0.0
    above: bool = True
    target: GateTarget = GateTarget.OUTPUT

    def describe(self) -> str:
        sign = ">" if self.above else "<"
        return f"{self.target.value} while {self.signal} {sign} {self.threshold:g}"


@dataclass(frozen=True)
class Position:
    """Multiply a contribution by ``signal - reference_mm`` (an axis position in mm, Pahk 2002 eq. 5)."""

    signal: str
    reference_mm: float = 0.0

    def describe(self) -> str:
        return f"x ({self.signal} - {self.reference_mm:g} mm)"


@dataclass(frozen=True)
class SubModel:
    """One physical effect's contribution to one axis output."""

    name: str
    effect: str
    input: InputSpec
    tf: DiscreteTF | ContinuousTF
    gain: float = 1.0
    gate: Gate | None = None
    #: The post-process gain this sub-model's ``gain`` is (Post-process 2024 eq. 6: ``g1``, ``g2``);
    #: sub-models sharing a name share the value. None: a fixed gain.
    gain_name: str | None = None
    #: Pahk 2002's slope term: the contribution times ``(position - reference_mm)``. None: factor 1.
    position: Position | None = None

    def signals(self) -> tuple[str, ...]:
        """The signals this sub-model reads: input, minus, gate and position, in that order."""
        names = (
            self.input.signal,
            self.input.minus,
            self.gate and self.gate.signal,
            self.position and self.position.signal,
        )
        return tuple(name for name in names if name)

    def describe_factors(self) -> str:
        """When and by what the contribution is multiplied: gate and position, or ``always``."""
        factors = [f.describe() for f in (self.gate, self.position) if f is not None]
        return "; ".join(factors) or "always"


@dataclass(frozen=True)
class Output:
    """One axis output (e.g. ``disp_z_um``): the sum of its sub-models, in um.

    ``residual`` (Swiss-lathe paper): a forest on smoothed door features added to that sum;
    ``bias_um``: a constant added to it (what probes taught, ``compd model export --updated``).
    """

    name: str
    submodels: tuple[SubModel, ...]
    residual: ResidualModel | None = None
    bias_um: float = 0.0


@dataclass(frozen=True)
class AmbientZero:
    """The thermal zero moves with the shop air: at start the fixed references of the inputs
    ``moves`` (temperatures: a cold machine is in equilibrium with the air) are shifted by
    ``signal - reference``, how much warmer the shop is than at calibration."""

    signal: str
    reference: float
    moves: tuple[str, ...] = ()


@dataclass(frozen=True)
class Model:
    """A machine's compensation model; discrete TFs are at ``sample_time_s``."""

    name: str
    sample_time_s: float
    outputs: tuple[Output, ...]
    ambient: AmbientZero | None = None

    def signals(self) -> tuple[str, ...]:
        """Every signal the model reads, in first-use order."""
        seen: dict[str, None] = {}
        for output in self.outputs:
            for sub in output.submodels:
                for name in sub.signals():
                    seen.setdefault(name, None)
        for output in self.outputs:
            if output.residual is not None:
                seen.setdefault(output.residual.signal, None)
        if self.ambient is not None:
            seen.setdefault(self.ambient.signal, None)
        return tuple(seen)
