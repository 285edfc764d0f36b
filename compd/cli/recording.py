"""What ``compd record`` does: run a config as a data logger into a directory, then say what to fit.

The config runs as :meth:`compd.service.config.loading.Config.recording` makes it:
its drivers and signals, checked every period exactly as ``compd run``
checks them, recorded by the service's own recorder, and nothing written to
the machine (no offsets, no status word, no heartbeat). A config with a
``simulation`` section records the simulated machine, whose PLC can serve
the twin's displacement as a probe's reading (``disp_z_um``, 0.3 um noise).
A real machine's config imports no pandas, toolkit or twin, as ``compd run``.
"""

from __future__ import annotations

import argparse
import asyncio
from collections.abc import Callable
from pathlib import Path

from compd.cli.daemon import install_signal_handlers, never_connected
from compd.cli.serving import config_from_arg, configure_logging
from compd.cli.terminal import Text, console, duration_text
from compd.errors import CompdError
from compd.service.config.loading import Config
from compd.service.daemon import Service
from compd.service.loop.clock import RealClock
from compd.service.loop.compensator import TickRecord
from compd.service.notify import SystemdNotifier
from compd.service.recording.recorder import NAME

#: A recording's file is closed at this size and the next one opened: under the 1 GiB that
#: ``compd fit --data`` reads (:data:`compd.files.data.MAX_FILE_BYTES`), so each file fits as it is.
FILE_BYTES = 1_000_000_000


def recordings(directory: Path) -> list[Path]:
    """The recorder's files in ``directory`` (:data:`compd.service.recording.recorder.NAME`), oldest first."""
    if not directory.is_dir():
        return []
    return sorted(p for p in directory.iterdir() if NAME.match(p.name))


def record_command(args: argparse.Namespace) -> int:
    config = config_from_arg(args.config)
    json_lines = {"auto": None, "json": True, "console": False}[args.log_format]
    configure_logging(json_lines=json_lines, level=args.log_level.upper())
    out_dir = args.out.expanduser().absolute()
    if recordings(out_dir):
        raise CompdError(
            f"{out_dir} already holds recordings: give 'compd record --out' a new or empty "
            "directory, so that the files there are this recording's alone"
        )
    duration_s = args.hours * 3600.0 if args.hours is not None else args.duration_s
    recording = config.recording(out_dir, max_file_bytes=FILE_BYTES)
    out = console()
    if config.doc.outputs or config.doc.status is not None:
        out.print(
            f"{config.path}: recording its signals only; its outputs and status word are not "
            "written (compd record never writes to the machine)"
        )
    every = max(1, round(3600.0 / config.doc.period_s))  # a line per recorded hour
    count = 0

    def progress(record: TickRecord) -> None:
        nonlocal count
        count += 1
        if count % every == 0:
            bad = [n for n, h in record.health.items() if h.name != "OK"]
            print(
                f"t {record.t_s / 3600:6.2f} h  {count} rows"
                + (f"  not ok: {', '.join(bad)}" if bad else ""),
                flush=True,
            )

    service: Service | None = None  # a real machine's
    if recording.simulation is not None:
        ticks = _record_simulated(recording, args.time_scale, duration_s, progress)
    elif args.time_scale is None:
        raise CompdError(
            f"--time-scale max runs on virtual time: only for a simulated machine, and "
            f"{config.path} has no 'simulation' section; give a factor, or leave it out"
        )
    else:
        service = Service(
            recording,
            clock=RealClock(args.time_scale),
            notifier=SystemdNotifier(),
            on_tick=progress,
        )
        ticks = asyncio.run(_record(service, duration_s))
    _print_result(recording, out_dir, ticks)
    if service is not None:
        # A calibration whose controller never answered recorded no reading of its signals.
        never_connected(service, ticks * recording.doc.period_s, "recording")
    return 0


def _record_simulated(
    config: Config,
    time_scale: float | None,
    duration_s: float | None,
    progress: Callable[[TickRecord], None],
) -> int:
    from compd.sim.plc.run import run_simulation  # the twin only where a config has one

    result = asyncio.run(
        run_simulation(
            config,
            time_scale=time_scale,
            duration_s=duration_s,
            on_tick=lambda service, machine, record: progress(record),
            service_hook=install_signal_handlers,
        )
    )
    return result.timing.ticks


async def _record(service: Service, duration_s: float | None) -> int:
    """A real machine: until ``duration_s`` of clock time, or SIGTERM / Ctrl-C."""
    install_signal_handlers(service)
    timing = await service.run(duration_s=duration_s)
    return timing.ticks


def suggested_inputs(units: dict[str, str]) -> list[str]:
    """The inputs the printed ``compd fit`` suggests: the temperatures (degC), else every signal.

    As the README's walk-through: a first model of the drift from the
    temperatures; a machine state (spindle speed, cutting power) is what
    ``compd diagnose`` and ``compd extend`` then test and add as its own effect.
    """
    temperatures = [name for name, unit in units.items() if unit == "degC"]
    return temperatures or list(units)


def _print_result(config: Config, out_dir: Path, ticks: int) -> None:
    """The files written, and the ``compd fit`` that reads them."""
    out = console()
    files = recordings(out_dir)
    if not files:
        raise CompdError(f"nothing was recorded into {out_dir} ({ticks} ticks); see the log above")
    length = duration_text(ticks * config.doc.period_s)
    out.print(f"recorded {ticks} ticks ({length} at {config.doc.period_s:g} s) into {out_dir}:")
    for path in files:
        out.print(f"  {path.name}  {path.stat().st_size:,} bytes")
    signals = config.doc.signals
    # A reference displacement (probe, dial gauge) is recorded in um: what a model predicts.
    outputs = [n for n, s in signals.items() if s.unit == "um"]
    inputs = suggested_inputs({n: s.unit for n, s in signals.items() if s.unit != "um"})
    # Several files of one run (rotated at the size limit) are one record to compd fit.
    data = files[0] if len(files) == 1 else out_dir
    if outputs:
        out.print(
            Text.assemble(
                "next: ",
                (
                    f"compd fit --data {data} --output {outputs[0]} "
                    f"--inputs {','.join(inputs)} --out model.yaml",
                    "bold",
                ),
            )
        )
        if others := [n for n in signals if n not in (*outputs, *inputs)]:
            out.print(
                f"  (the temperatures first; {', '.join(others)}: what compd diagnose and "
                "compd extend test next, as in the README's walk-through)"
            )
    else:
        out.print(
            "no signal in um was recorded: a calibration run needs the reference displacement "
            "(a probe or dial gauge, unit um) as a signal, the output compd fit identifies"
        )
