"""The thermal twin of a 3-axis milling centre: a simulated machine for tests and trying compd.

:func:`simulate_scenario` generates a logged run (a pandas DataFrame with the
columns of :data:`COLUMNS`); :class:`MachineTwin` advances the same machine
one sample at a time, for closed-loop use.
"""

from compd.errors import ScenarioError
from compd.sim.machine import NODES, Geometry, HeatLaws, Link, MachineParameters
from compd.sim.scenarios import (
    SCENARIOS,
    scenario_inputs,
    simulate_scenario,
)
from compd.sim.sensors import COLUMNS, SensorBank, SensorSet
from compd.sim.thermal import (
    InputRecord,
    MachineInputs,
    MachineTwin,
    ThermalNetwork,
    ThermalRecord,
    TwinState,
    equilibrium,
    simulate_record,
)

__all__ = [
    "COLUMNS",
    "NODES",
    "SCENARIOS",
    "Geometry",
    "HeatLaws",
    "InputRecord",
    "Link",
    "MachineInputs",
    "MachineParameters",
    "MachineTwin",
    "ScenarioError",
    "SensorBank",
    "SensorSet",
    "ThermalNetwork",
    "ThermalRecord",
    "TwinState",
    "equilibrium",
    "scenario_inputs",
    "simulate_record",
    "simulate_scenario",
]
