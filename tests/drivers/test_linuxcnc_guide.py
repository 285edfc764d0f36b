"""deploy/README.md's LinuxCNC recipe, run as written on a headless LinuxCNC, and the nets it warns against.

The HAL file is the test machine's own plus the guide's HAL block verbatim;
the driver runs with the guide's config settings. The offset compd writes
must reach ``axis.z.eoffset-counts`` with the enable on; a HAL file that
nets those pins itself must be refused, naming the net, on every start.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from compd.drivers.linuxcnc import LinuxCncDriver, LinuxCncSettings
from compd.errors import DriverProtocolError

from . import linuxcnc_machine
from .contract import run_calls
from .linuxcnc_machine import Machine

GUIDE = Path(__file__).parents[2] / "deploy" / "README.md"


def linuxcnc_section() -> str:
    text = GUIDE.read_text()
    start = text.index("### LinuxCNC")
    return text[start : text.index("\n## ", start)]


def guide_hal_lines() -> str:
    (block,) = re.findall(r"```text\n(.*?)```", linuxcnc_section(), re.S)
    return block


def guide_driver(machine: Machine) -> LinuxCncDriver:
    """The driver with the guide's settings, and the test machine's INI (OFFSET_AV_RATIO checked)."""
    config = next(
        yaml.safe_load(b)
        for b in re.findall(r"```yaml\n(.*?)```", linuxcnc_section(), re.S)
        if "linuxcnc" in b
    )
    (driver,) = config["drivers"].values()
    settings = {**driver["settings"], "ini_file": str(machine.folder / "sim.ini")}
    return LinuxCncDriver(LinuxCncSettings(**settings), now=time.monotonic, base_dir=Path())


@pytest.fixture
def guide_machine(tmp_path) -> Iterator[Machine]:
    running = linuxcnc_machine.start(tmp_path, guide_hal_lines())
    yield running
    running.stop()


@pytest.fixture
def netted_machine(tmp_path) -> Iterator[Machine]:
    """LinuxCNC whose HAL file nets Z's offset pins itself, as an earlier guide showed."""
    lines = (
        "setp axis.z.eoffset-scale  0.0001\n"
        "net compd-z-enable  => axis.z.eoffset-enable\n"
        "net compd-z-counts  => axis.z.eoffset-counts\n"
    )
    running = linuxcnc_machine.start(tmp_path, linuxcnc_machine.SIGNALS + lines)
    yield running
    running.stop()


def test_the_guides_recipe_moves_the_axis(guide_machine):
    """With the guide's HAL lines and settings, 3 counts written reach axis.z.eoffset-counts, enable TRUE."""
    driver = guide_driver(guide_machine)
    run_calls(driver, ("write", {"axis.z": 3.0}))
    counts = guide_machine.halcmd("getp", "axis.z.eoffset-counts")
    enable = guide_machine.halcmd("getp", "axis.z.eoffset-enable")
    (values,) = run_calls(driver, ("read", ["T-spindle-degC", "T-shopfloor-degC"]))
    run_calls(driver, ("write", {"axis.z": 0.0}))
    assert (counts, enable) == ("3", "TRUE")
    assert values == {"T-spindle-degC": 0.0, "T-shopfloor-degC": 0.0}


def test_offset_pins_netted_in_the_hal_file_are_refused_naming_the_net(netted_machine):
    """A HAL file's own net of axis.z.eoffset-* is refused with the fix, on the first start and every retry."""
    for _ in range(2):  # the retry found compd's signals from the first attempt and went quiet
        with pytest.raises(DriverProtocolError, match=r"compd-z-.*remove the HAL file's net"):
            run_calls(guide_driver(netted_machine), ("write", {"axis.z": 3.0}))
    assert netted_machine.halcmd("getp", "axis.z.eoffset-counts") == "0"
