"""The numeric core: transfer functions, compilation, simulation, identification, diagnosis, metrics.

numpy and scipy only: nothing here reads files, logs or knows about asyncio,
so every result can be checked against scipy with ``assert_allclose``.
"""

from compd.model.compiled import CompiledModel, ModelState, compile_model
from compd.model.diagnose import CandidateScore, Diagnosis, diagnose_residue
from compd.model.identify import Identification, IdentifiedTF, identify
from compd.model.metrics import Comparison, ErrorStats, fit_percent
from compd.model.run import SimulationResult, TickRunner, simulate
from compd.model.structure import (
    Gate,
    GateTarget,
    InputSpec,
    Model,
    Output,
    Position,
    SubModel,
)
from compd.model.transfer import ContinuousTF, DiscreteTF
from compd.model.windows import FailingWindow, failing_windows

__all__ = [
    "CandidateScore",
    "Comparison",
    "CompiledModel",
    "ContinuousTF",
    "Diagnosis",
    "DiscreteTF",
    "ErrorStats",
    "FailingWindow",
    "Gate",
    "GateTarget",
    "Identification",
    "IdentifiedTF",
    "InputSpec",
    "Model",
    "ModelState",
    "Output",
    "Position",
    "SimulationResult",
    "SubModel",
    "TickRunner",
    "compile_model",
    "diagnose_residue",
    "failing_windows",
    "fit_percent",
    "identify",
    "simulate",
]
