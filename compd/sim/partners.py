"""Second sensors beside critical ones: a redundant Pt100 at the spindle bearings and in the air.

A second Pt100 beside a critical one is common practice: it lets the daemon
tell a drifting or offset sensor from a machine that really warmed up
(:mod:`compd.service.loop.redundancy`). The simulated machine carries two:

- ``T_spindle_b_degC`` on the spindle bearings, beside ``T_spindle_degC``;
- ``T_ambient_b_degC`` in the shop air, beside ``T_ambient_degC``.

Each is a Pt100 class A as the others (:mod:`compd.sim.sensors`): the node's
true temperature through its own first-order lag (20-60 s), its own fixed
offset within the class-A tolerance and white noise of 0.015 degC. They are
served to the simulated PLC only, not logged in a twin data file
(:data:`compd.sim.sensors.COLUMNS` is the contract of every data file and model
fitted on one).

Their lags, offsets and noise come from a random stream of their own
(``np.random.default_rng([seed, 3])`` in the simulated machine), so every
other column of a run stays what it was without them, to the last bit.
"""

from __future__ import annotations

import numpy as np

from compd.sim.sensors import LivePt100s, SensorSet

#: Partner column -> the node (or boundary) it sits on, as :data:`compd.sim.sensors.TEMPERATURE_SENSORS`.
PARTNER_SENSORS: dict[str, str] = {
    "T_spindle_b_degC": "bearings",
    "T_ambient_b_degC": "ambient",
}
#: Partner column -> the logged column it stands beside.
PARTNER_OF: dict[str, str] = {
    "T_spindle_b_degC": "T_spindle_degC",
    "T_ambient_b_degC": "T_ambient_degC",
}


class PartnerBank(LivePt100s):
    """The partner sensors read live, one sample at a time, beside a :class:`~compd.sim.sensors.SensorBank`.

    ``rng`` draws their lags and offsets once, then their noise each sample;
    give it a stream of its own.
    """

    def __init__(self, sample_time_s: float, rng: np.random.Generator) -> None:
        super().__init__(
            SensorSet.draw(rng, sites=PARTNER_SENSORS), PARTNER_SENSORS, sample_time_s, rng
        )
