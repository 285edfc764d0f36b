"""A compd with its HTTP server, running against the simulated machine in a thread, held still on request.

The service runs unchanged (:func:`compd.sim.plc.run.run_simulation`, virtual
time) on its own event loop in a background thread. :meth:`RunningCompd.hold_at`
stops time after a given number of ticks -- the loop keeps serving HTTP while
the next tick waits -- so ``/metrics``, ``/status.json`` and the page can be
compared at one instant, with no timing in the test.
"""

from __future__ import annotations

import asyncio
import json
import threading
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import yaml

from compd.files.yamlplace import resolve_path
from compd.service.config.loading import load_config
from compd.service.daemon import Service
from compd.sim.plc.run import run_simulation
from tests.acceptance.conftest import machine_doc

BUNDLED_MODEL = resolve_path("bundled:simulated_model.yaml", Path("."))
#: A guard against a hang, not a timing: generous for a busy CI machine.
HANG_S = 300.0
#: Faults the machine injects (simulated s): an input goes NaN, then the PLC drops off the network.
FAULTS = [
    {"kind": "nan", "signal": "T_spindle_degC", "at_s": 30, "duration_s": 60},
    {"kind": "drop", "driver": "plc", "at_s": 100, "duration_s": 10},
]


def http_config(directory: Path, model: Path = BUNDLED_MODEL, **http: Any) -> Path:
    """The bundled simulated machine with ``http`` on a free port (``port: 0``) and two faults."""
    simulation = {
        "scenario": "production",
        "hours": 2,
        "seed": 1,
        "sample_time_s": 1.0,
        "faults": FAULTS,
    }
    doc = machine_doc(directory, model, simulation=simulation, http={"port": 0, **http})
    doc["signals"]["T_spindle_degC"].pop("redundant")  # one sensor: the NaN is a signal fault
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


class HeldClock:
    """The service's clock, which stops before a tick once ``target`` ticks have run."""

    def __init__(self, inner: Any, target: int) -> None:
        self.inner = inner
        self.target: int | None = target
        self.held = threading.Event()
        self.release = threading.Event()
        self._ticks = 0

    def now(self) -> float:
        return float(self.inner.now())

    def wall(self) -> float:
        return float(self.inner.wall())

    def wall_at(self, t: float) -> float:
        return float(self.inner.wall_at(t))

    async def sleep_until(self, t: float) -> None:
        await self.inner.sleep_until(t)
        if self.target is not None and self._ticks >= self.target:
            self.target = None
            self.release.clear()
            self.held.set()
            while not self.release.is_set():
                await asyncio.sleep(0.002)  # the loop answers HTTP meanwhile
        self._ticks += 1


class RunningCompd:
    """A handle on the service in its thread: its URL, hold and release, fetch."""

    def __init__(self, config_path: Path, first_hold: int) -> None:
        self.config = load_config(config_path)
        self.service: Service | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.clock: HeldClock | None = None
        self.first_hold = first_hold
        self.error: BaseException | None = None
        self.started = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _hook(self, service: Service) -> None:
        self.clock = HeldClock(service.clock, self.first_hold)
        service.clock = self.clock  # type: ignore[assignment]
        self.service = service
        self.loop = asyncio.get_running_loop()
        self.started.set()

    def _run(self) -> None:
        try:
            asyncio.run(run_simulation(self.config, service_hook=self._hook))
        except BaseException as exc:
            self.error = exc
        finally:
            self.started.set()
            if self.clock is not None:
                self.clock.held.set()

    @property
    def url(self) -> str:
        assert self.service is not None and self.service.http is not None
        return self.service.http.url

    def wait_held(self) -> None:
        assert self.started.wait(HANG_S) and self.clock is not None, self.error
        assert self.clock.held.wait(HANG_S), "the service never reached the tick"
        assert self.error is None, self.error

    def hold_at(self, ticks: int) -> None:
        """Let time run until ``ticks`` ticks have run in all, then hold it."""
        assert self.clock is not None
        self.clock.held.clear()
        self.clock.target = ticks
        self.clock.release.set()
        self.wait_held()

    def get(self, path: str, method: str = "GET") -> tuple[int, dict[str, str], bytes]:
        """Status, headers and body of one request (an HTTP error status is returned, not raised)."""
        request = urllib.request.Request(self.url + path.lstrip("/"), method=method)
        try:
            with urllib.request.urlopen(request, timeout=HANG_S) as response:
                return response.status, dict(response.headers), response.read()
        except urllib.error.HTTPError as exc:
            return exc.code, dict(exc.headers), exc.read()

    def json(self, path: str) -> Any:
        status, _, body = self.get(path)
        assert status == 200, (path, status, body)
        return json.loads(body)

    def stop(self) -> None:
        if self.service is not None and self.loop is not None and self.thread.is_alive():
            self.loop.call_soon_threadsafe(self.service.stop)
        if self.clock is not None:
            self.clock.target = None
            self.clock.release.set()
        self.thread.join(HANG_S)


@contextmanager
def running_compd(config_path: Path, *, hold_at: int) -> Iterator[RunningCompd]:
    """The service started and held after ``hold_at`` ticks; stopped at the end."""
    run = RunningCompd(config_path, hold_at)
    run.thread.start()
    try:
        run.wait_held()
        yield run
    finally:
        run.stop()
