"""Driver supervision: one :class:`DriverLink` per configured driver.

A link runs reads and writes under a timeout and never raises into the loop:
a failed read returns no values, a failed write returns ``False``, and the
link goes down. While down, it reconnects in the background with
exponential backoff while the loop goes on. The first failure of an episode
logs ERROR, repeats log DEBUG, the recovery logs INFO
(:class:`compd.faultlog.FaultLog`). A reconnect is not yet a recovery: the
episode ends with the first read or write that succeeds after it, so a peer
that accepts connections but never answers is one fault, not one per
reconnect, and its reconnects keep backing off.

A write the device refuses (:class:`~compd.errors.DriverRefusedError`: a
Modbus exception response, say a PLC answering every write with exception 2)
is not a link down: the connection answers, and reconnecting would not change
the answer, only make the episode start again at every successful read. It is
a fault episode of its own (ERROR once, DEBUG while it lasts, INFO at the
first accepted write): the link stays up, :attr:`DriverLink.refusing_writes`
says so, and :attr:`DriverLink.state` is ``refusing writes`` until then.

Drivers raise only compd's :class:`~compd.errors.DriverError` family, and a
read returns floats for the addresses asked. A driver that breaks that
contract (a ``TypeError`` from a reply of the wrong shape, a string for a
value) has a bug, but one bad reply must not end the loop: the link takes
any :class:`Exception` from a driver call, and a read of the wrong shape, as
a driver fault like any other (it goes down and reconnects), and logs the
unexpected exception's type with its traceback once per link.
``CancelledError`` and ``KeyboardInterrupt`` are not :class:`Exception` and
pass through.

A call that completes at its first step (the simulated driver, a serial
sensor polled in the background: values already at hand) arms no timer
(:func:`within`): only a call that waits needs one, and it gets the limit
less what its first step took, as ``asyncio.timeout`` around the whole call
would give it.
"""

from __future__ import annotations

import asyncio
import math
import numbers
import time
from collections.abc import Awaitable, Callable, Coroutine, Generator, Mapping, Sequence
from types import CoroutineType
from typing import Any, TypeVar

import structlog

from compd.drivers.base import Driver
from compd.errors import DriverError, DriverProtocolError, DriverRefusedError
from compd.faultlog import EventSink, FaultLog
from compd.service.loop.clock import Clock

log = structlog.get_logger("compd.service.loop.links")

T = TypeVar("T")


class DriverLink:
    """One supervised driver: timeouts, failure accounting, reconnect with exponential backoff.

    Backoff after the n-th consecutive failure: ``min(backoff_max_s, backoff_min_s * 2**(n-1))``.
    """

    def __init__(
        self,
        name: str,
        driver: Driver,
        clock: Clock,
        *,
        timeout_s: float,
        backoff_min_s: float = 1.0,
        backoff_max_s: float = 60.0,
    ) -> None:
        self.name = name
        self.driver = driver
        self.clock = clock
        self.timeout_s = timeout_s
        self.backoff_min_s = backoff_min_s
        self.backoff_max_s = backoff_max_s
        self.up = False
        self.failures = 0  # consecutive, until a read or write succeeds
        self.reconnects = 0
        #: Driver exceptions outside the contract (not DriverError, TimeoutError, OSError): bugs.
        self.unexpected = 0
        self._fault = FaultLog(log, driver=name)
        #: Writes refused by a device that answers: an episode apart from the link's (module docstring).
        self._refused = FaultLog(log, driver=name)
        self.next_attempt_s = -math.inf
        self._connecting: asyncio.Task[None] | None = None
        self._ever_up = False
        #: A read or write has succeeded since start: until then the peer is "not connected"
        #: wherever a person looks (a closed port, or a peer that accepts and never answers).
        self.answered = False
        #: The last failure's message ("" before any): what a run that never connected says.
        self.last_error = ""
        self._unexpected: set[type[BaseException]] = set()  # exception types logged once
        #: Told ``(operation, seconds)`` after each read or write, failed ones too (:mod:`compd.service.http.metrics`).
        self.observe: Callable[[str, float], None] | None = None

    @property
    def faults(self) -> int:
        """Fault episodes so far: the link's (a first failure to the next successful read or write)
        and its refused writes' (a first refusal to the next accepted write)."""
        return self._fault.episodes + self._refused.episodes

    @property
    def refusing_writes(self) -> bool:
        """The device refused the last write (it answers, and refuses): no write accepted since."""
        return self._refused.active

    def report_to(self, sink: EventSink) -> None:
        """Tell ``sink`` of each fault episode's start and end (:class:`compd.faultlog.Event`)."""
        self._fault.sink = sink
        self._refused.sink = sink

    @property
    def state(self) -> str:
        """``up``, ``refusing writes``, ``down`` (it answered before), or ``not connected`` (never answered)."""
        if self.up and self.answered:
            return "refusing writes" if self._refused.active else "up"
        return "down" if self.answered else "not connected"

    @property
    def connecting(self) -> bool:
        """A reconnect is under way in the background."""
        return self._connecting is not None

    async def open(self) -> None:
        """First connection attempt; a failure is logged and retried by :meth:`poll`."""
        await self._connect()

    def poll(self) -> None:
        """While down, start a reconnect in the background when its backoff has passed."""
        if self.up or self._connecting is not None or self.clock.now() < self.next_attempt_s:
            return
        self._connecting = asyncio.get_running_loop().create_task(self._connect())
        self._connecting.add_done_callback(self._connected)

    def _connected(self, _: asyncio.Task[None]) -> None:
        self._connecting = None

    async def _connect(self) -> None:
        try:
            async with asyncio.timeout(self.timeout_s):
                await self.driver.open()
        except Exception as exc:  # any driver fault reconnects (module docstring)
            self._failed("open", exc)
            return
        if self._ever_up:
            self.reconnects += 1
        self.up = True
        if self._fault.active:  # recovered only once a read or write succeeds
            log.debug("driver connection reopened", driver=self.name, after_failures=self.failures)
        else:
            log.info("driver connected", driver=self.name)
            self._ever_up = True

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        """Values by address; empty when the link is down or the read failed (never raises)."""
        if not self.up:
            self.poll()
            return {}
        started_s = time.perf_counter()
        try:
            read = await within(self.driver.read(points), self.timeout_s, started_s)
            values = _floats(read, points)
        except Exception as exc:  # any driver fault reconnects (module docstring)
            self._failed("read", exc)
            return {}
        finally:
            if self.observe is not None:
                self.observe("read", time.perf_counter() - started_s)
        self._succeeded()
        return values

    async def write(self, values: Mapping[str, float]) -> bool:
        """Write; ``False`` when the link is down or the write failed (never raises)."""
        if not self.up:
            self.poll()
            return False
        started_s = time.perf_counter()
        try:
            await within(self.driver.write(values), self.timeout_s, started_s)
        except DriverRefusedError as exc:  # it answers and refuses: the link stays up
            self.answered = True
            self.last_error = _text(exc)
            self._refused.failed("driver write refused", error=self.last_error)
            return False
        except Exception as exc:  # any other driver fault reconnects (module docstring)
            self._failed("write", exc)
            return False
        finally:
            if self.observe is not None:
                self.observe("write", time.perf_counter() - started_s)
        self._succeeded()
        if self._refused.active:  # (cleared() does nothing otherwise: no call every tick)
            self._refused.cleared("driver write accepted again")
        return True

    async def close(self) -> None:
        if self._connecting is not None:
            self._connecting.cancel()
        try:
            async with asyncio.timeout(self.timeout_s):
                await self.driver.close()
        except Exception as exc:  # close() never raises into the loop
            log.debug("driver close failed", driver=self.name, error=repr(exc))
        self.up = False

    def _succeeded(self) -> None:
        self.answered = True
        if self._fault.active:
            event = "driver reconnected" if self._ever_up else "driver connected"
            also = "reconnected" if self._ever_up else None
            self._fault.cleared(event, also=also, after_failures=self.failures)
            self.failures, self._ever_up = 0, True

    def _failed(self, action: str, exc: Exception) -> None:
        if not isinstance(exc, (DriverError, TimeoutError, OSError)):
            self.unexpected += 1
            self._log_unexpected(action, exc)
        self._fault.failed(f"driver {action} failed", error=_text(exc))
        self.last_error = _text(exc)
        self.up = False
        self.failures += 1
        backoff_s = min(self.backoff_max_s, self.backoff_min_s * 2 ** (self.failures - 1))
        self.next_attempt_s = self.clock.now() + backoff_s

    def _log_unexpected(self, action: str, exc: Exception) -> None:
        """Once per exception type: the traceback of a driver raising outside its contract."""
        if type(exc) in self._unexpected:
            return
        self._unexpected.add(type(exc))
        log.error(
            f"driver {action} raised {type(exc).__name__}, not a DriverError: a bug in the "
            "driver; the link treats it as a fault and reconnects",
            driver=self.name,
            exc_info=exc,
        )


async def within(call: Awaitable[T], timeout_s: float, started_s: float) -> T:
    """``await call`` under a limit of ``timeout_s`` from ``started_s`` (``perf_counter``).

    A coroutine that returns (or raises) at its first step never waited, so
    no timer is armed: ``asyncio.timeout`` costs a timer, a heap entry and two
    running-loop look-ups (a ``getpid`` each on Python 3.11), twice a tick,
    for calls that cannot time out. One that waits is resumed under
    ``asyncio.timeout`` with what is left of the limit (``TimeoutError`` as before).
    """
    # A native coroutine (every driver's) is told by its type; the ABC's check costs more.
    if type(call) is not CoroutineType and not isinstance(call, Coroutine):  # the plain way
        async with asyncio.timeout(timeout_s - (time.perf_counter() - started_s)):
            return await call
    try:
        first = call.send(None)
    except StopIteration as done:
        result: T = done.value
        return result
    async with asyncio.timeout(timeout_s - (time.perf_counter() - started_s)):
        return await _Resumed(call, first)


class _Resumed(Awaitable[T]):
    """A coroutine already stepped once (it yielded ``first`` to the event loop), awaited from there."""

    __slots__ = ("_call", "_first")

    def __init__(self, call: Coroutine[Any, Any, T], first: Any) -> None:
        self._call = call
        self._first = first

    def __await__(self) -> Generator[Any, Any, T]:
        call, yielded = self._call, self._first
        while True:
            try:
                sent = yield yielded
            except GeneratorExit:
                call.close()
                raise
            except BaseException as exc:  # a cancellation (the timeout's too) goes into the call
                try:
                    yielded = call.throw(exc)
                except StopIteration as done:
                    result: T = done.value
                    return result
            else:
                try:
                    yielded = call.send(sent)
                except StopIteration as done:
                    result = done.value
                    return result


def _floats(values: object, points: Sequence[str]) -> dict[str, float]:
    """A read's values as floats, for the addresses asked (others dropped); a non-number is a fault."""
    if type(values) is not dict and not isinstance(values, Mapping):  # dict: no ABC check
        raise DriverProtocolError(f"read returned {type(values).__name__}, not values by address")
    floats = {}
    for address in points:
        if address not in values:
            continue
        value = values[address]
        if type(value) is float:  # what most drivers return: no ABC check, no conversion
            floats[address] = value
            continue
        if not isinstance(value, numbers.Real):  # numpy's scalars are Real too
            raise DriverProtocolError(
                f"read returned {type(value).__name__} {value!r:.40} for {address!r}, not a number"
            )
        try:
            floats[address] = float(value)
        except OverflowError as exc:  # an int beyond any float
            raise DriverProtocolError(
                f"read returned an integer beyond any float for {address!r}"
            ) from exc
    return floats


def _text(exc: BaseException) -> str:
    if isinstance(exc, TimeoutError):
        return "timed out"
    return f"{type(exc).__name__}: {exc}"
