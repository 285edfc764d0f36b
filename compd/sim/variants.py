"""Configurations of the twin other than the reference machine, for testing model updates.

Post-process 2024 applies a model calibrated in one machine configuration to another
(an exchangeable spindle head, another position in the workspace) and
re-weighs its sub-models from a few probe measurements. These variants change
the physics in the same spirit, in ways the model's temperature inputs do not
see directly, so a model fitted on the reference machine fits them poorly
while its TFs still have the right time constants.
"""

from __future__ import annotations

import dataclasses

from compd.errors import ScenarioError
from compd.sim.machine import MachineParameters


def _spindle_head() -> MachineParameters:
    """Another spindle head: 75 % of the bearing friction goes into the unsensed shaft (40 % on the reference)."""
    base = MachineParameters()
    return dataclasses.replace(base, heat=dataclasses.replace(base.heat, bearing_to_shaft=0.75))


def _long_nose() -> MachineParameters:
    """A longer spindle head: shaft and bearing cartridge twice as long below the headstock."""
    base = MachineParameters()
    geometry = dataclasses.replace(
        base.geometry,
        shaft_length_z_m=2 * base.geometry.shaft_length_z_m,
        cartridge_length_z_m=2 * base.geometry.cartridge_length_z_m,
    )
    return dataclasses.replace(base, geometry=geometry)


#: Variant name -> (parameters, one-line description).
VARIANTS: dict[str, tuple[MachineParameters, str]] = {
    "reference": (MachineParameters(), "the reference machine (default)"),
    "spindle-head": (
        _spindle_head(),
        "another spindle head: 75 percent of bearing friction into the shaft, not 40",
    ),
    "long-nose": (_long_nose(), "a longer spindle head: shaft and cartridge twice as long"),
}


def machine_variant(name: str) -> MachineParameters:
    """The parameters of variant ``name``; an unknown name lists the known ones."""
    try:
        return VARIANTS[name][0]
    except KeyError:
        raise ScenarioError(
            f"there is no machine variant {name!r}; choose one of {', '.join(VARIANTS)}"
        ) from None
