"""The soak's sensor faults: a model input's sensor wrong for a while, and what it cost the compensation.

A fault of :data:`~compd.sim.soakfaults.SENSOR_KINDS` strikes through the
simulated machine's own fault injection (what a config's ``simulation.faults``
does, :meth:`~compd.sim.plc.machine.SimulatedMachine.inject`), on the model's
inputs that are configured signals, each in turn (:func:`model_inputs`):

- ``sensor_offset``: the sensor reads the truth +15 or -25 degC (a plausible
  wrong value, within every limit of its own);
- ``glitch``: it reads 60 degC for 40 s;
- ``stuck``: it keeps the value it had when the fault struck;
- ``wire_break``: it reads 327.67 (the top of an int16 point at 0.01 degC: a
  transmitter's broken wire, high), -200 (low) or NaN.

What a fault cost is measured against the same shift without faults: a
reference run of the same config and seed, made before the soak with the same
service on the same machine and nothing struck
(:func:`~compd.sim.plc.run.run_simulation`). Both machines step the same twin
through the same scenario with the sensor noise drawn in the same order, so
their thermal errors are the same and their compensated errors
``e = true_um + offset_um`` (:mod:`compd.sim.plc.machine`) differ only by what
compd wrote. Per fault, on the soak's axis::

    excess_um = max |e_soak(t)| - max |e_reference(t)|,   at_s <= t <= at_s + duration_s + 600 s

over the fault and the 10 minutes after it (a wrong input lives on in the
model's slow states). That window is measured, not attributed: another fault
in it (a kill, a link drop, a PLC reset, the next sensor fault) adds its own
cost, and a service restarted earlier may carry other states than the
reference's. Each line names the other faults drawn into its window, and
the summary is given apart for the windows with none but :data:`QUIET`
ones. A negative excess is a window the faulted run happened to do better
in. The reference is the running service with its slew limit,
blending and checks, not the model run offline on the fault-free readings:
that would also count what the safety stage does as the fault's cost.

Beside it, how long the service stood in for the sensor (health
``ESTIMATED``, :mod:`compd.service.loop.plausibility`) from the fault until the
next fault on the same input: a stand-in that outlasts its fault by far
explains an excess that does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from compd.files.modelfile import load_model
from compd.service.config.loading import Config
from compd.service.loop.compensator import TickRecord
from compd.service.loop.signals import Health
from compd.sim.plc.machine import AXES, SimulatedMachine
from compd.sim.plc.run import run_simulation
from compd.sim.plc.settings import SimFaultDoc
from compd.sim.soakfaults import Fault

#: How long after a sensor fault its cost is still measured (s): the model's slow states.
AFTER_S = 600.0
#: Faults that write nothing to the machine and leave the service's state as it was: a window
#: holding only these is a sensor fault's own.
QUIET = ("bad_model", "sighup", "slow_clients")
#: What each kind and variant makes of the reading: the machine's fault kind and value (degC).
MACHINE_FAULTS: dict[tuple[str, str], tuple[str, float | None]] = {
    ("sensor_offset", "+15"): ("offset", 15.0),
    ("sensor_offset", "-25"): ("offset", -25.0),
    ("glitch", "60"): ("value", 60.0),
    ("stuck", ""): ("stuck", None),
    ("wire_break", "high"): ("value", 327.67),
    ("wire_break", "low"): ("value", -200.0),
    ("wire_break", "nan"): ("nan", None),
}


@dataclass
class SensorEpisode:
    """One sensor fault of the soak, and the largest compensated error in its window, um."""

    kind: str
    variant: str
    signal: str
    at_s: float
    duration_s: float
    #: max |e| over the window in the soak, and in the fault-free reference (NaN: not measured).
    max_error_um: float = math.nan
    reference_um: float = math.nan
    #: Ticks' time the service stood in for the sensor, from the fault to the next one on it (s).
    estimated_s: float = 0.0
    #: The kinds of the other faults drawn into the window.
    others: tuple[str, ...] = ()

    @property
    def alone(self) -> bool:
        """No fault but :data:`QUIET` ones in the window: the excess is this fault's own."""
        return all(kind in QUIET for kind in self.others)

    @property
    def window_s(self) -> tuple[float, float]:
        """The fault and the :data:`AFTER_S` after it (s)."""
        return self.at_s, self.at_s + self.duration_s + AFTER_S

    @property
    def excess_um(self) -> float:
        """What the window's largest error exceeds the reference's by (um; see the module docstring)."""
        return self.max_error_um - self.reference_um


def machine_fault(fault: Fault, signal: str, at_s: float) -> SimFaultDoc:
    """``fault`` as the simulated machine injects it into ``signal``'s sensor from ``at_s``."""
    kind, value = MACHINE_FAULTS[fault.kind, fault.variant]
    return SimFaultDoc.model_validate(
        {"kind": kind, "at_s": at_s, "duration_s": fault.duration_s, "signal": signal}
        | ({} if value is None else {"value": value})
    )


def model_inputs(config: Config) -> list[str]:
    """The model's inputs that are configured signals, in the model's order: the sensor faults' turn."""
    assert config.model_path is not None, "a soak runs a compensating config"
    names = load_model(config.model_path).model.signals()
    return [name for name in names if name in config.doc.signals]


class SensorFaults:
    """A soak's sensor faults on ``machine``: each on the next model input in turn, then measured.

    ``episodes`` (the soak result's list) gets one :class:`SensorEpisode` per fault struck.
    """

    def __init__(
        self, config: Config, machine: SimulatedMachine, axis: str, episodes: list[SensorEpisode]
    ) -> None:
        self.config = config
        self.machine = machine
        self.axis = axis
        self.episodes = episodes
        self.inputs = model_inputs(config)
        self._latest: dict[str, SensorEpisode] = {}  # per input, its last fault
        self._struck: list[tuple[Fault, SensorEpisode]] = []
        #: The fault-free run's compensated error (:meth:`run_reference`); None: not run.
        self.reference_um: np.ndarray | None = None

    def strike(self, fault: Fault) -> None:
        """``fault`` into the next input's sensor from now (the service reads it at its next tick)."""
        signal = self.inputs[len(self.episodes) % len(self.inputs)]
        at_s = self.machine.now_s
        self.machine.inject(machine_fault(fault, signal, at_s))
        episode = SensorEpisode(fault.kind, fault.variant, signal, at_s, fault.duration_s)
        self.episodes.append(episode)
        self._latest[signal] = episode
        self._struck.append((fault, episode))

    def tick(self, record: TickRecord) -> None:
        """A tick of a service: a stand-in's time goes to the last fault on that input."""
        for signal, episode in self._latest.items():
            if record.health.get(signal) is Health.ESTIMATED:
                episode.estimated_s += self.config.doc.period_s

    async def run_reference(self) -> None:
        """The shift without faults; before the soak's machine starts (it takes the same port and files)."""
        result = await run_simulation(self.config)
        self.reference_um = compensated_um(result.machine, self.axis)

    def measure(self, faults: Sequence[Fault]) -> None:
        """Each episode's largest |error| over its window, in the soak and (if run) the reference.

        ``faults``: all the soak's faults, as drawn: those in an episode's window are named in it.
        """
        for fault, episode in self._struck:
            start_s, end_s = episode.window_s
            episode.others = tuple(
                f.kind
                for f in faults
                if f is not fault and f.at_s <= end_s and f.at_s + f.duration_s >= start_s
            )
        soak_um = compensated_um(self.machine, self.axis)
        dt_s = self.machine.sample_time_s
        for episode in self.episodes:
            start_s, end_s = episode.window_s
            window = slice(math.ceil(start_s / dt_s - 1e-9), math.floor(end_s / dt_s + 1e-9) + 1)
            episode.max_error_um = _largest(soak_um[window])
            if self.reference_um is not None:
                episode.reference_um = _largest(self.reference_um[window])


def compensated_um(machine: SimulatedMachine, axis: str) -> np.ndarray:
    """The compensated error on config axis ``axis`` at each sample stepped: ``true + offset``, um."""
    (served,) = (a for a in machine.axes.values() if a.name == axis)
    i = AXES.index(served.twin_axis)
    return machine.true_um[: machine.k + 1, i] + machine.offset_um[: machine.k + 1, i]


def _largest(error_um: np.ndarray) -> float:
    return float(np.max(np.abs(error_um))) if error_um.size else math.nan


def excess_lines(episodes: list[SensorEpisode]) -> list[str]:
    """The verdict's table: one line per sensor fault, its window's largest error and the excess."""
    lines = [
        f"{'sensor fault':<26}{'signal':<22}{'at':>8}{'for':>6}"
        f"{'stand-in':>9}{'max |e|':>10}{'no fault':>10}{'excess':>9}"
        "   (um, over the fault + 10 min; the other faults in that window)"
    ]
    for e in episodes:
        what = f"{e.kind} {e.variant}".strip()
        lines.append(
            f"{what:<26}{e.signal:<22}{e.at_s / 60:>7.1f}m{e.duration_s:>5.0f}s"
            f"{e.estimated_s:>8.0f}s{e.max_error_um:>10.2f}{e.reference_um:>10.2f}{e.excess_um:>+9.2f}"
            + (f"   also: {', '.join(e.others)}" if e.others else "")
        )
    for name, chosen in (
        ("excess over the fault-free run", episodes),
        (
            f"  with no other fault but {', '.join(QUIET)} in the window",
            [e for e in episodes if e.alone],
        ),
    ):
        excess = [e.excess_um for e in chosen if math.isfinite(e.excess_um)]
        if excess:
            lines.append(
                f"{name}: median {np.median(excess):+.2f} um, largest {max(excess):+.2f} um "
                f"({len(excess)} sensor faults)"
            )
    return lines
