"""Daily use of models: load by bundled name, list what is installed, go back, and say what runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml

from compd.files.yamlplace import resolve_path
from compd.service.config.loading import load_config
from tests.clirun import compd

from .test_live_terminal import short_dir, simulated_config

__all__ = ["short_dir"]  # the fixture, shared

WORKTREE_CONFIG = Path(__file__).resolve().parents[2] / "config"


def other_model(directory: Path) -> Path:
    """The bundled model renamed: same inputs, other bytes, so another sha256."""
    text = resolve_path("bundled:simulated_model.yaml", Path(".")).read_text()
    path = directory / "other.yaml"
    path.write_text(text.replace('name: "twin-z"', 'name: "twin-z-other"'))
    return path


def test_model_load_takes_a_bundled_name_like_model_check(short_dir: Path) -> None:
    """`compd model load bundled:NAME` reads the bundled file, as `compd model check bundled:NAME` does."""
    config = simulated_config(short_dir)
    compd("model", "load", other_model(short_dir), "--config", config)
    out = compd("model", "load", "bundled:simulated_model.yaml", "--config", config)
    assert "twin-z" in out and "config's own model" in out
    assert not (short_dir / "state" / "current-model").exists()


def test_model_list_shows_what_runs_next_and_load_previous_goes_back(short_dir: Path) -> None:
    """`compd model list` marks the model the next start runs and the previous; `load --previous` returns to it."""
    config = simulated_config(short_dir)
    compd("model", "load", other_model(short_dir), "--config", config)
    rows = compd("model", "list", "--config", config).splitlines()
    other = next(r for r in rows if "twin-z-other" in r)
    own = next(r for r in rows if "twin-z " in r)
    assert "next start" in other and "previous" in own and "config's model" in own
    compd("model", "load", "--previous", "--config", config)
    rows = compd("model", "list", "--config", config).splitlines()
    assert "next start" in next(r for r in rows if "twin-z " in r)
    assert "previous" in next(r for r in rows if "twin-z-other" in r)


def test_run_says_at_start_and_end_that_it_runs_an_installed_model(short_dir: Path) -> None:
    """After `compd model load`, a simulated `compd run` names the installed model and the way back, first and last."""
    config = simulated_config(short_dir)
    compd("model", "load", other_model(short_dir), "--config", config)
    done = subprocess.run(
        [sys.executable, "-m", "compd.cli", "run", "--config", str(config), "--time-scale", "max",
         "--duration-s", "120"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stdout.splitlines() if line.strip()]
    first, last = " ".join(lines[:2]), " ".join(lines[-2:])  # a notice may wrap
    for said in (first, last):
        assert "model twin-z-other installed by 'compd model load'" in said, done.stdout
    assert "compd model load --previous" in done.stdout


def test_the_bundled_quick_start_keeps_its_recordings_bounded() -> None:
    """The simulated quick start keeps at most 40 MB of recordings: repeated runs do not pile up."""
    config = load_config(WORKTREE_CONFIG / "simulated.yaml")
    assert config.doc.recorder.max_total_bytes <= 40_000_000
    assert yaml.safe_load((WORKTREE_CONFIG / "simulated.yaml").read_text())["recorder"]
