"""The habits docs/development.md claims are gated: ruff, its formatter and mypy pass at the versions the lock pins."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.installed import console_script, run_installed

ROOT = Path(__file__).parent.parent


def _run(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=900)


@pytest.mark.parametrize("argv", [("check", "."), ("format", "--check", ".")], ids=" ".join)
def test_ruff_is_clean(argv: tuple[str, ...]) -> None:
    """``ruff check .`` and ``ruff format --check .`` report nothing (drivers, tests and benchmarks included)."""
    ruff = console_script("ruff")  # this environment's, at the lock's version: not PATH's
    if ruff is None:
        pytest.skip("ruff is not installed: pip install -c .ci/requirements.lock -e '.[dev]'")
    done = _run(str(ruff), *argv)
    assert done.returncode == 0, done.stdout + done.stderr


def test_mypy_is_clean_on_the_package_and_its_drivers() -> None:
    """mypy (strict on the numeric core) passes on compd, the drivers checked as the compd.drivers installed."""
    pytest.importorskip("mypy", reason="pip install -c .ci/requirements.lock -e '.[dev]'")
    done = run_installed(sys.executable, "-m", "mypy")
    assert done.returncode == 0, done.stdout + done.stderr
