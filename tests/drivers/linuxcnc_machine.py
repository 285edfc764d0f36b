"""A headless LinuxCNC (uspace, simulated XYZ mill) for the driver tests.

:func:`start` writes an INI and HAL file into a folder and runs Debian's
``linuxcnc`` on them. Its DISPLAY is a small script under ``/usr/bin/python3``
(LinuxCNC's Python) that takes the machine out of estop, switches it on,
homes every joint (immediate homing: no switches in a simulation) and writes
``ready`` (its pid); LinuxCNC runs until :meth:`Machine.stop` ends that
script, and the ``linuxcnc`` start script then shuts everything down as
after a GUI's exit. (SIGTERM to the start script itself waits for the
display: bash runs a trap only when its foreground child returns.)

Z has external offsets (``OFFSET_AV_RATIO = 0.2`` of ``MAX_VELOCITY = 2``
mm/s: 0.4 mm/s), and an ``integ`` of 1.0 on the servo thread gives the
machine's own clock (``machine-time-s``), so a test measures the ramp in
servo-thread seconds, not in the wall-clock time of a busy CI machine.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import pwd
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

MAX_VELOCITY_MM_PER_S = 2.0
OFFSET_AV_RATIO = 0.2
LOCK = Path("/tmp/linuxcnc.lock")  # the linuxcnc script's: one LinuxCNC per machine
# pytest-xdist may hand this module's tests to two workers: the second waits
# for the first's LinuxCNC to stop (HAL allows one per host).
TURN = Path(tempfile.gettempdir()) / "compd-linuxcnc-tests.lock"
SKIP = "run .ci/install-system-packages"

_AXIS = f"""
MAX_VELOCITY = {MAX_VELOCITY_MM_PER_S}
MAX_ACCELERATION = 20
MIN_LIMIT = -100
MAX_LIMIT = 100
"""
_JOINT = f"""
TYPE = LINEAR
HOME_SEQUENCE = 0
{_AXIS}"""

INI = f"""
[EMC]
MACHINE = compd-test
VERSION = 1.1
[DISPLAY]
DISPLAY = {{folder}}/display.py
[TASK]
TASK = milltask
CYCLE_TIME = 0.010
[RS274NGC]
PARAMETER_FILE = sim.var
[EMCIO]
EMCIO = io
CYCLE_TIME = 0.100
TOOL_TABLE = sim.tbl
[EMCMOT]
EMCMOT = motmod
SERVO_PERIOD = 1000000
[HAL]
HALFILE = sim.hal
[TRAJ]
COORDINATES = XYZ
LINEAR_UNITS = mm
ANGULAR_UNITS = degree
MAX_LINEAR_VELOCITY = {MAX_VELOCITY_MM_PER_S}
[KINS]
JOINTS = 3
KINEMATICS = trivkins coordinates=XYZ
[AXIS_X]
{_AXIS}
[AXIS_Y]
{_AXIS}
[AXIS_Z]
OFFSET_AV_RATIO = {OFFSET_AV_RATIO}
{_AXIS}
[JOINT_0]
{_JOINT}
[JOINT_1]
{_JOINT}
[JOINT_2]
{_JOINT}
"""

HAL = """
loadrt [KINS]KINEMATICS
loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD num_joints=[KINS]JOINTS
loadrt integ names=machine-clock
addf motion-command-handler servo-thread
addf motion-controller servo-thread
addf machine-clock servo-thread
setp machine-clock.in 1.0
net machine-time-s machine-clock.out
net Xpos joint.0.motor-pos-cmd => joint.0.motor-pos-fb
net Ypos joint.1.motor-pos-cmd => joint.1.motor-pos-fb
net Zpos joint.2.motor-pos-cmd => joint.2.motor-pos-fb
net estop-loop iocontrol.0.user-enable-out iocontrol.0.emc-enable-in
net tool-prep-loop iocontrol.0.tool-prepare iocontrol.0.tool-prepared
net tool-change-loop iocontrol.0.tool-change iocontrol.0.tool-changed
"""
#: The HAL lines a test adds to :data:`HAL` by default: the signal the tests read.
SIGNALS = "newsig T-spindle-degC float\n"

DISPLAY = """#!/usr/bin/python3
# A headless DISPLAY: estop off, machine on, home all, then wait for SIGTERM.
import os, signal, sys, time
import linuxcnc
c, s = linuxcnc.command(), linuxcnc.stat()
def wait(done, what):
    end = time.monotonic() + 30
    while time.monotonic() < end:
        s.poll()
        if done():
            return
        time.sleep(0.05)
    sys.exit("display.py: no " + what + " within 30 s")
c.state(linuxcnc.STATE_ESTOP_RESET)
wait(lambda: s.task_state == linuxcnc.STATE_ESTOP_RESET, "estop reset")
c.state(linuxcnc.STATE_ON)
wait(lambda: s.task_state == linuxcnc.STATE_ON, "machine on")
c.mode(linuxcnc.MODE_MANUAL)
c.wait_complete()
c.home(-1)
wait(lambda: all(s.homed[:3]), "homing")
signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "ready"), "w") as f:
    f.write(str(os.getpid()))
while True:
    time.sleep(3600)
"""

MDI = """
import sys, linuxcnc
c, s = linuxcnc.command(), linuxcnc.stat()
c.mode(linuxcnc.MODE_MDI)
c.wait_complete()
c.mdi(sys.argv[1])
c.wait_complete()
"""


def linuxcnc_missing() -> str | None:
    """Why LinuxCNC cannot run here, or None."""
    if shutil.which("linuxcnc") is None or shutil.which("halcmd") is None:
        return f"LinuxCNC not installed (linuxcnc-uspace): {SKIP}"
    probe = subprocess.run(
        ["/usr/bin/python3", "-c", "import hal, linuxcnc"], capture_output=True, check=False
    )
    if probe.returncode:
        return f"LinuxCNC's Python modules (hal, linuxcnc) do not import: {SKIP}"
    if LOCK.exists():
        return f"another LinuxCNC is running ({LOCK} exists): one per machine"
    return None


@dataclass
class Machine:
    """A running headless LinuxCNC."""

    folder: Path
    process: subprocess.Popen[bytes]
    fifo: Path | None
    turn: int  # the file descriptor holding TURN

    def halcmd(self, *args: str) -> str:
        return subprocess.run(
            ["halcmd", *args], capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()

    def mdi(self, command: str) -> None:
        """Run one MDI command (e.g. ``M3 S1200``) through LinuxCNC's task, as an operator would."""
        subprocess.run(["/usr/bin/python3", "-c", MDI, command], timeout=30, check=True)

    def log(self) -> str:
        return (self.folder / "linuxcnc.log").read_text(errors="replace")[-3000:]

    def service_config(self, *, temperature_checks: dict | None = None, **output: object) -> dict:
        """Config changes for compd on this LinuxCNC: HAL pins as signals, axis.z in 0.1 um as offset Y.

        ``temperature_checks``: the spindle temperature's ``checks``; ``output``: more keys of Y.
        """
        on_mill = {"driver": "mill", "unit": "degC"}
        temperature: dict[str, object] = {**on_mill, "address": "T-spindle-degC"}
        if temperature_checks is not None:
            temperature["checks"] = temperature_checks
        return {
            "drivers": {
                "mill": {
                    "type": "linuxcnc",
                    "settings": {"component": "svc", "ini_file": str(self.folder / "sim.ini")},
                    "timeout_s": 2.0,
                }
            },
            "signals": {
                "T_spindle_degC": temperature,
                "spindle_speed_rpm": {**on_mill, "address": "spindle.0.speed-out", "unit": "rpm"},
            },
            "outputs": {
                "Y": {
                    "driver": "mill",
                    "address": "axis.z",
                    "encoding": {"type": "int", "scale": 10},
                    "max_rate_um_per_s": 5.0,
                    **output,
                }
            },
        }

    def stop(self) -> None:
        """Shut LinuxCNC down as its GUI's exit would; kill what is left after 30 s."""
        if self.process.poll() is None:
            ready = self.folder / "ready"
            with contextlib.suppress(OSError, ValueError):
                os.kill(int(ready.read_text()), signal.SIGTERM)
            try:
                self.process.wait(30)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait(10)
        if self.fifo is not None:
            shutil.rmtree(self.fifo, ignore_errors=True)
        if self.turn >= 0:
            os.close(self.turn)  # releases the flock
            self.turn = -1


def start(folder: Path, hal_lines: str = SIGNALS) -> Machine:
    """Start LinuxCNC headless from files written into ``folder``; pytest.skip if it cannot run.

    ``hal_lines`` are appended to the HAL file (e.g. a guide's lines, as a user would copy them).
    """
    turn = os.open(TURN, os.O_CREAT | os.O_RDWR, 0o666)
    deadline = time.monotonic() + 300  # a hang guard
    while True:
        try:
            fcntl.flock(turn, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() > deadline:
                os.close(turn)
                pytest.skip(f"another test process kept LinuxCNC ({TURN}) for 300 s")
            time.sleep(0.2)
    reason = linuxcnc_missing()
    if reason:
        os.close(turn)
        pytest.skip(reason)
    (folder / "sim.ini").write_text(INI.format(folder=folder))
    (folder / "sim.hal").write_text(HAL + hal_lines)
    (folder / "sim.tbl").write_text("")
    display = folder / "display.py"
    display.write_text(DISPLAY)
    display.chmod(0o755)
    env = {**os.environ, "HOME": str(folder)}  # its debug and print files go there
    fifo = None
    if os.geteuid() == 0:
        # rtapi_app refuses root without a user to drop to, and that user
        # must be able to create its FIFO (pytest's tmp folders are 0700).
        env["RTAPI_UID"] = str(pwd.getpwnam("nobody").pw_uid)
        fifo = Path(tempfile.mkdtemp(prefix="compd-rtapi-"))
        fifo.chmod(0o777)
        env["RTAPI_FIFO_PATH"] = str(fifo / "rtapi_fifo")
    with (folder / "linuxcnc.log").open("wb") as log:
        process = subprocess.Popen(
            ["linuxcnc", str(folder / "sim.ini")],
            cwd=folder,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    machine = Machine(folder, process, fifo, turn)
    deadline = time.monotonic() + 60  # a hang guard, not a measurement
    while not (folder / "ready").exists():
        if process.poll() is not None or time.monotonic() > deadline:
            machine.stop()
            pytest.skip(f"LinuxCNC (uspace) did not start here:\n{machine.log()}")
        time.sleep(0.1)
    return machine
