"""Suite-wide isolation: a command run in-process configures logging; the next test starts clean."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
import structlog

if TYPE_CHECKING:
    from tests.mosquitto import Mosquitto


@pytest.fixture(autouse=True)
def _isolated_logging() -> Iterator[None]:
    """Restore the root logger and structlog's defaults after each test (no handler on a closed stream)."""
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    structlog.reset_defaults()
    root.handlers = handlers
    root.setLevel(level)


@pytest.fixture(autouse=True)
def _no_exported_width(monkeypatch: pytest.MonkeyPatch) -> None:
    """No ``COLUMNS``/``LINES`` unless a test exports them: pytest-xdist's workers inherit
    ``COLUMNS=80``, which a piped compd now honours (``COLUMNS=120 compd diagnose | less``),
    so a test would see an 80-column table under ``-n 2`` and a whole one alone."""
    monkeypatch.delenv("COLUMNS", raising=False)
    monkeypatch.delenv("LINES", raising=False)


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Mosquitto]:
    """A mosquitto of the test's own, on a free port (the telemetry, roll-out and fleet tests)."""
    from tests.mosquitto import Mosquitto  # paho only for the tests that ask

    folder = tmp_path / "broker"
    folder.mkdir()
    mosquitto = Mosquitto(folder).start()
    yield mosquitto
    mosquitto.stop()
