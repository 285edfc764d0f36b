"""The ``simulation:`` section of a compd config: the simulated machine the config runs against.

With it, ``compd run`` starts the machine in the same process before the
service, and ``compd simulate-machine`` starts the machine alone. The rest of
the config is unchanged: the drivers connect to the simulated controllers as
they would to a real machine (a ``type: modbus`` driver to a simulated Modbus
TCP server at its host and port, and so on). The section's schema is the
config's (:mod:`compd.service.config.simdoc`), checked as the config is read.
"""

from __future__ import annotations

from pydantic import ValidationError

from compd.errors import ConfigFileError
from compd.service.config.loading import Config, validation_error
from compd.service.config.simdoc import (
    FaultKind,
    SimFaultDoc,
    SimMisprobeDoc,
    SimProbesDoc,
    SimulationDoc,
    TwinAxis,
)

__all__ = [
    "FaultKind",
    "SimFaultDoc",
    "SimMisprobeDoc",
    "SimProbesDoc",
    "SimulationDoc",
    "TwinAxis",
    "simulation_of",
]


def simulation_of(config: Config) -> SimulationDoc:
    """The config's ``simulation:`` section, validated; ConfigFileError names what does not fit."""
    if config.simulation is None:
        raise ConfigFileError(
            config.path,
            "this config has no 'simulation' section",
            where="simulation",
            fix="Add one (see config/simulated.yaml) or run compd against a real machine",
        )
    if isinstance(config.simulation, SimulationDoc):  # the loader checked it
        return config.simulation
    try:
        return SimulationDoc.model_validate(config.simulation)
    except ValidationError as exc:
        raise validation_error(exc, config.path, config.root, ("simulation",)) from exc
