"""The numeric core: transfer functions, compilation, simulation, identification, diagnosis, metrics.

numpy and scipy only: nothing here reads files, logs or knows about asyncio,
so every result can be checked against scipy with ``assert_allclose``.

The names below are loaded on first use (PEP 562): the daemon, which only
compiles and steps models, never loads the identification stack. (The
function ``identify`` is not among them: once loaded, the submodule of the
same name would shadow it; import it from :mod:`compd.model.identify`.)
"""

from __future__ import annotations

import importlib
from typing import Any

#: Public name -> the module that defines it.
_EXPORTS = {
    "CandidateScore": "compd.model.diagnose",
    "Comparison": "compd.model.metrics",
    "CompiledModel": "compd.model.compiled",
    "ContinuousTF": "compd.model.transfer",
    "Diagnosis": "compd.model.diagnose",
    "DiscreteTF": "compd.model.transfer",
    "ErrorStats": "compd.model.metrics",
    "FailingWindow": "compd.model.windows",
    "Gate": "compd.model.structure",
    "GateTarget": "compd.model.structure",
    "Identification": "compd.model.identify",
    "IdentifiedTF": "compd.model.identify",
    "InputSpec": "compd.model.structure",
    "Model": "compd.model.structure",
    "ModelState": "compd.model.compiled",
    "Output": "compd.model.structure",
    "Position": "compd.model.structure",
    "SimulationResult": "compd.model.run",
    "SubModel": "compd.model.structure",
    "TickRunner": "compd.model.run",
    "compile_model": "compd.model.compiled",
    "diagnose_residue": "compd.model.diagnose",
    "failing_windows": "compd.model.windows",
    "fit_percent": "compd.model.metrics",
    "simulate": "compd.model.run",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'compd.model' has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)
