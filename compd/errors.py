"""Every exception compd raises on purpose, in one place.

The numeric core raises :class:`ModelError` (a model that cannot be run:
unstable, non-causal, malformed coefficients). Everything that reads a file
raises an :class:`InputFileError` subclass whose message names the file, the
place in it and what would fix it, so a user never has to guess.
"""

from __future__ import annotations


class CompdError(Exception):
    """Base class of compd's own errors."""


class ModelError(CompdError, ValueError):
    """A model that compd refuses to run (unstable, non-causal, malformed).

    ``where`` is the place in the model (``outputs.disp_z_um.submodels[2]``)
    when the caller knows it.
    """

    def __init__(self, message: str, *, where: str = "") -> None:
        self.message = message
        self.where = where
        super().__init__(f"{where}: {message}" if where else message)


class InputFileError(CompdError):
    """A file compd was asked to read is malformed.

    The message reads ``FILE: PLACE: what is wrong. FIX`` so it can be acted
    on without opening the source.
    """

    def __init__(self, path: object, message: str, *, where: str = "", fix: str = "") -> None:
        self.path = str(path)
        self.where = where
        self.message = message
        self.fix = fix
        parts = [self.path]
        if where:
            parts.append(where)
        text = ": ".join([*parts, message])
        if fix:
            text = f"{text}. {fix}"
        super().__init__(text)


class ModelFileError(InputFileError):
    """A model file (YAML) that does not describe a runnable model."""


class DataFileError(InputFileError):
    """A data file (CSV, Parquet) that cannot be used as logged machine data."""


class RecorderError(CompdError):
    """The recorder could not write its CSV files (disk full, no permission).

    Recording is a side job of the compensation loop: the loop logs this
    error and keeps compensating; the rows of the failed tick are lost.
    """


class ControlError(CompdError):
    """The control socket cannot be served or reached (no daemon, stale socket, no reply)."""


class NotRunningError(ControlError):
    """No daemon listens on the control socket (no socket file, or a stale one)."""


class ConfigFileError(InputFileError):
    """A daemon configuration file (YAML) that compd refuses to start with."""


class DriverError(CompdError):
    """A machine driver could not read or write; the loop reconnects and goes on.

    Drivers raise only this family: a library's own exceptions are translated
    at the driver boundary, so the loop needs to know three cases, not every
    protocol stack's.
    """


class DriverTimeoutError(DriverError):
    """The device did not answer within the read or write timeout."""


class DriverDisconnectedError(DriverError):
    """The connection is down (refused, reset, not yet open)."""


class DriverProtocolError(DriverError):
    """The device answered, but not as expected (unknown address, bad reply, wrong type)."""


class DriverRefusedError(DriverProtocolError):
    """The device answered a request with a refusal (a Modbus exception response).

    The connection is sound: reconnecting does not change the answer. A write
    refused so is a fault episode of its own until a write is accepted
    (:class:`compd.service.loop.links.DriverLink`), not a link down and up again.
    """


class ScenarioError(CompdError, ValueError):
    """A twin scenario that cannot be generated: unknown name, bad duration or sample time."""
