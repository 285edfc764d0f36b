"""The numeric core: transfer functions, compilation, simulation and metrics.

numpy and scipy only: nothing here reads files, logs or knows about asyncio,
so every result can be checked against scipy with ``assert_allclose``.
"""

from compd.model.compiled import CompiledModel, ModelState, compile_model
from compd.model.metrics import Comparison, ErrorStats, fit_percent
from compd.model.run import SimulationResult, TickRunner, simulate
from compd.model.structure import Gate, GateTarget, InputSpec, Model, Output, SubModel
from compd.model.transfer import ContinuousTF, DiscreteTF

__all__ = [
    "Comparison",
    "CompiledModel",
    "ContinuousTF",
    "DiscreteTF",
    "ErrorStats",
    "Gate",
    "GateTarget",
    "InputSpec",
    "Model",
    "ModelState",
    "Output",
    "SimulationResult",
    "SubModel",
    "TickRunner",
    "compile_model",
    "fit_percent",
    "simulate",
]
