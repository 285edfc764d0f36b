"""Bounds on what a model may ask of the daemon: orders, delays, sub-models, gains.

A model file is small, but what it describes need not be: ``nk: 1000000``
is a delay line of a million states per sub-model, ``gain: 1e308`` an
output that overflows on the first tick, an order of 3000 a root-finding
problem of minutes. Thermal-error models are a handful of low-order
sub-models (Horejs 2010-004: orders 1-4, delays of a few samples, gains of
micrometres per kelvin), so compd refuses anything beyond these bounds at
compile time, before one state is allocated. docs/commands.md's
'Model files' states the same numbers.
"""

from __future__ import annotations

#: Highest TF order (coefficients per ``num`` or ``den``: ``MAX_ORDER + 1``).
MAX_ORDER = 32
#: Longest input delay, in samples at the run sample time (10 min at 1 s).
MAX_DELAY_SAMPLES = 600
#: Sub-models per model, all outputs together: a lag bank on 24 inputs at 5 time
#: constants is 120 (first-order, so its step stays small: the states bound it).
MAX_SUBMODELS = 256
#: Compiled states (sub-models x longest delay line); the per-tick step is a
#: dense matrix of this size squared (2048: 32 MiB, a few ms per tick).
MAX_STATES = 2048
#: Largest ``|gain * static gain|`` and step-response peak per sub-model (um per
#: input unit): a metre of displacement per unit of any input is no thermal model.
MAX_GAIN_UM_PER_UNIT = 1e6
#: Longest sample time (s) a model is compiled for.
MAX_SAMPLE_TIME_S = 3600.0
#: Samples of the unit-step response simulated at compile time (the finite-output check).
CHECK_SAMPLES = 1000
