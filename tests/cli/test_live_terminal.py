"""`compd run` on a terminal: one live view, redrawn in place, with the logs in a panel under it."""

from __future__ import annotations

import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from compd.files.yamlplace import resolve_path
from tests.acceptance.conftest import free_port
from tests.service.daemon_setup import write_config

from .terminal import Screen, run_in_terminal

HEADER = "simulated machine production"
LOG_LINE = re.compile(r"\[\s*(debug|info|warning|error|critical)\s*\]|\"log_level\"")


@pytest.fixture
def short_dir() -> Iterator[Path]:
    directory = Path(tempfile.mkdtemp(prefix="compd-tty-", dir="/tmp"))
    yield directory
    shutil.rmtree(directory, ignore_errors=True)


def simulated_config(directory: Path, **simulation: object) -> Path:
    """bundled:simulated.yaml with its model, on a free port, its files under ``directory``."""
    bundled = resolve_path("bundled:simulated.yaml", Path("."))
    doc = yaml.safe_load(bundled.read_text())
    doc["model"] = str(bundled.parent / doc["model"])
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(directory / "state"), "save_every_ticks": 60}
    doc["control_socket"] = str(directory / "c.sock")
    doc["simulation"] |= simulation
    path = directory / "sim.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def one_view(argv: list[str], header: str) -> tuple[Screen, int, int]:
    """Run at 120x40; the screen, its one header's line and its log panel's, no log line between."""
    screen = run_in_terminal(argv, columns=120, rows=40)
    text = "\n".join(screen.lines)
    assert screen.returncode == 0, text
    headers = [i for i, line in enumerate(screen.lines) if header in line]
    assert len(headers) == 1, f"{len(headers)} copies of the header:\n{text}"
    head = headers[0]
    panel = next(
        i for i in range(head, len(screen.lines)) if "warnings and errors" in screen.lines[i]
    )
    view = screen.lines[head:panel]
    assert not [line for line in view if LOG_LINE.search(line)], "\n".join(view)
    return screen, head, panel


def test_live_view_is_drawn_once_with_the_fault_in_its_warnings_panel(short_dir: Path) -> None:
    """At 120x40: one header in all the scrollback, the fault's error in the panel, no log in the view."""
    config = simulated_config(
        short_dir, faults=[{"kind": "drop", "driver": "plc", "at_s": 120, "duration_s": 40}]
    )
    argv = ["run", "--config", str(config), "--time-scale", "max", "--duration-s", "600"]
    screen, head, panel = one_view(argv, HEADER)
    assert "/ 0:10:00 (100 %)" in screen.lines[head], screen.lines[head]
    view = screen.lines[head:panel]
    assert any("offset written um (sign x drift" in line for line in view), "\n".join(view)
    panel_end = next(i for i in range(panel + 1, len(screen.lines)) if "╰" in screen.lines[i])
    shown = "\n".join(screen.lines[panel:panel_end])
    assert "driver read failed" in shown or "driver open failed" in shown, shown
    # After the view: the summary, and the records kept while it ran, in full.
    after = "\n".join(screen.lines[panel_end:])
    assert "thermal error at the tool centre point" in after and "driver reconnected" in after


def test_start_up_logs_come_before_the_live_view_not_after_it(short_dir: Path) -> None:
    """The quick start on a terminal: model, socket and driver lines above the view, in order, not after it."""
    argv = ["run", "--config", str(simulated_config(short_dir)), "--time-scale", "max",
            "--duration-s", "600"]  # fmt: skip
    screen, head, panel = one_view(argv, HEADER)
    text = "\n".join(screen.lines)
    for line in ("control socket listening", "driver connected", "initial state"):
        assert line in "\n".join(screen.lines[:head]), text
        assert line not in "\n".join(screen.lines[panel:]), text
    assert "x0 real time" not in text and "real time  status" in screen.lines[head]


def test_the_first_frame_says_starting_not_x0() -> None:
    """The rate is measured from the first frame: nothing simulated yet reads "starting", then x(sim/real)."""
    from compd.cli.simulate import speed_up

    assert speed_up(0.0, 0.0) == speed_up(0.0, 0.25) == "starting"
    assert speed_up(600.0, 2.0) == "x300" and speed_up(36_000.0, 3.0) == "x12,000"


def test_run_on_a_real_machine_config_shows_the_same_live_view(short_dir: Path) -> None:
    """Without a simulation (the replay driver): one header, progress to --duration-s, the warning in the panel."""
    config = write_config(short_dir, {"control_socket": str(short_dir / "c.sock")})
    config.state_dir.mkdir(parents=True, exist_ok=True)
    # An ERROR at start (the file set aside).
    (config.state_dir / "state.json").write_text("{ not json")
    argv = ["run", "--config", str(config.path), "--time-scale", "50", "--duration-s", "120"]
    screen, head, panel = one_view(argv, "compd model example-gated-arx-y")
    text = "\n".join(screen.lines)
    assert "t 0:02:00 / 0:02:00 (100 %)" in screen.lines[head], screen.lines[head]
    view = screen.lines[head:panel]
    assert any("model drift um  sign  offset written um (sign x drift" in line for line in view)
    # Logged before the first frame: on the terminal above the view, as it came, and counted
    # in the panel; not held back and printed again after the view (issue 36, item 17).
    assert re.search(r"warnings and errors \([1-9]", screen.lines[panel]), text
    assert any("saved state cannot be read" in line for line in screen.lines[:head]), text
    panel_end = next(i for i in range(panel + 1, len(screen.lines)) if "╰" in screen.lines[i])
    assert not any("saved state cannot be read" in line for line in screen.lines[panel_end:])


def test_a_view_taller_than_the_terminal_is_cropped_not_scrolled(short_dir: Path) -> None:
    """At 80x10 the view does not fit: frames are cropped, so the scrollback still has one header."""
    config = simulated_config(short_dir)
    argv = ["run", "--config", str(config), "--time-scale", "max", "--duration-s", "600"]
    screen = run_in_terminal(argv, columns=80, rows=10)
    text = "\n".join(screen.lines)
    assert screen.returncode == 0, text
    assert sum(HEADER in line for line in screen.lines) == 1, text
    assert "thermal error at the tool centre point" in text


def test_at_80_columns_the_header_is_one_line_and_no_title_is_cut(short_dir: Path) -> None:
    """At 80x40: the run's header on one line, the axis titles in two, the summary's "RMS reduction" whole."""
    config = simulated_config(short_dir)
    argv = ["run", "--config", str(config), "--time-scale", "max", "--duration-s", "600"]
    screen = run_in_terminal(argv, columns=80, rows=40)
    text = "\n".join(screen.lines)
    assert screen.returncode == 0, text
    head = next(i for i, line in enumerate(screen.lines) if "(100 %)" in line)
    assert screen.lines[head].rstrip().endswith("ok"), text  # the status, not wrapped below
    assert screen.lines[head + 1].startswith("input"), text
    signals = tuple(yaml.safe_load(config.read_text())["signals"])
    last_input = max(i for i, line in enumerate(screen.lines) if line.startswith(signals))
    axis_titles = next(
        i for i in range(last_input, len(screen.lines)) if screen.lines[i][:1] == "Z"
    )
    assert axis_titles - last_input - 1 <= 2, text  # the title lines between inputs and row Z
    assert "…" not in text and "reduction" in text, text
