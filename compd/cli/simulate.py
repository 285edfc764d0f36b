"""``compd run`` on a config with a ``simulation`` section, and ``compd simulate-machine``.

``compd run`` starts the simulated machine in-process and shows it live
(inputs, model, offsets, the true and the compensated error), then prints the
summary: uncompensated vs compensated error per axis and the faults counted.
``compd simulate-machine`` serves the machine alone, for a compd started
elsewhere (another terminal, another host, systemd).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import time
from typing import Any

from rich.text import Text

from compd.cli.args import positive_float, set_option
from compd.cli.livescreen import FRAME_S, LiveScreen
from compd.cli.modellist import installed_notice
from compd.cli.serving import config_from_arg, configure_logging
from compd.cli.terminal import console
from compd.cli.tickview import level_text, progress, tick_view, too_wide
from compd.service.config.loading import Config
from compd.service.daemon import Service
from compd.service.loop.compensator import TickRecord
from compd.sim.plc.machine import SimulatedMachine
from compd.sim.plc.run import SimulationResult, run_simulation, serve_machine
from compd.sim.plc.settings import SimulationDoc
from compd.sim.plc.view import fault_table, summary_table


def register(commands: Any) -> None:
    sim = commands.add_parser(
        "simulate-machine",
        help="serve the simulated machine of a config's 'simulation' section, for a compd elsewhere",
        description="Serve the simulated machine of a config's 'simulation' section on the "
        "protocols its drivers speak (as a PLC would), for a 'compd run' in another process "
        "or on another host to read and write, with a line every 10 simulated minutes, until "
        "Ctrl-C or SIGTERM; then the machine's summary.",
    )
    sim.add_argument("--config", required=True, metavar="FILE.yaml", help="path or bundled:NAME")
    sim.add_argument(
        "--time-scale",
        type=positive_float,
        default=1.0,
        metavar="X",
        help="run the machine X times faster than real time (default 1); give compd the same",
    )
    set_option(sim)
    sim.set_defaults(handler=_simulate_machine)


#: When stdout is not a terminal and no --live-every is given: a progress line this often (s).
PIPED_EVERY_S = 3600.0


def speed_up(simulated_s: float, real_s: float) -> str:
    """How much faster than real time the simulated clock runs, ``x210``; ``starting`` before it has.

    Measured from the first frame (not from the process's start, whose loading
    is no simulation), so the first frame, with nothing simulated yet, says
    ``starting`` rather than ``x0``.
    """
    if simulated_s <= 0.0 or real_s <= 0.0:
        return "starting"
    return f"x{simulated_s / real_s:,.0f}"


def run_simulated(
    config: Config, time_scale: float | None, duration_s: float | None, live_every: int | None
) -> int:
    """``compd run`` for a config with a simulated machine: live view, then the summary."""
    out = console()
    notice = installed_notice(config)
    if notice is not None:  # before the live view, and again under the summary
        out.print(Text(notice, style="bold yellow"))
    units = {name: s.unit for name, s in config.doc.signals.items()}
    signs = {axis: o.sign for axis, o in config.doc.outputs.items()}
    screen = LiveScreen(out) if out.is_terminal else None
    if screen is None and live_every is None:  # piped: a line each simulated hour, not silence
        live_every = max(1, round(PIPED_EVERY_S / config.doc.period_s))
        sim = SimulationDoc.model_validate(config.simulation or {})
        speed = "virtual time" if time_scale is None else f"x{time_scale:g} real time"
        print(
            f"simulated machine: {sim.scenario}, {sim.hours:g} h, seed {sim.seed}, on {speed}; "
            "a line each simulated hour (--live-every N: every N ticks)",
            flush=True,
        )
    last_frame = 0.0
    count = 0

    latest: tuple[Service, SimulatedMachine, TickRecord] | None = None
    first: tuple[float, float] | None = None  # the first frame's simulated and real time (s)

    def draw(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        assert screen is not None
        counters = service.status()["counters"]
        shown = {k: counters[k] for k in ("ticks", "signal_faults", "reconnects")}
        # Progress counts to where this run stops: --duration-s, else the scenario's end.
        end_s = duration_s if duration_s is not None else machine.duration_s
        nonlocal first
        if first is None:
            first = (machine.now_s, time.perf_counter())
        rate = speed_up(machine.now_s - first[0], time.perf_counter() - first[1])
        head = Text.assemble(
            ("simulated machine ", "bold"),
            f"{machine.doc.scenario} (seed {machine.doc.seed})  {progress(machine.now_s, end_s)}  ",
            f"{rate}{' real time' if rate.startswith('x') else ''}  status ",
            level_text(record),
        )
        if head.cell_len > out.width:  # 80 columns: the short form, still one line
            head = Text.assemble(
                ("simulated machine ", "bold"),
                f"{machine.doc.scenario} seed {machine.doc.seed}  {progress(machine.now_s, end_s)}  "
                f"{rate}  ",
                level_text(record),
            )
        truth = machine.truth_now()
        twin = {
            "true error um": {axis: f"{t:+.2f}" for axis, (t, _, _) in truth.items()},
            "compensated um": {axis: f"{c:+.2f}" for axis, (_, _, c) in truth.items()},
        }
        view = tick_view(head, record, units, signs, shown, twin)
        if too_wide(out, view):  # 80 columns: two-line titles, nothing wraps into a third
            view = tick_view(head, record, units, signs, shown, twin, narrow=True)
        screen.show(view)

    def on_tick(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        nonlocal last_frame, count, latest
        count += 1
        if screen is not None:
            latest = (service, machine, record)
            now = time.perf_counter()
            if now - last_frame >= FRAME_S:
                last_frame = now
                draw(service, machine, record)
        elif live_every and count % live_every == 0:
            true_um = machine.truth_now()
            print(
                f"t {record.t_s / 3600:6.2f} h  "
                + "  ".join(
                    f"{axis}: offset {record.offsets_um[axis]:+7.2f} um, error {t:+7.2f} -> "
                    f"{c:+6.2f} um"
                    for axis, (t, _, c) in true_um.items()
                ),
                flush=True,
            )

    def hook(service: Service) -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, service.stop)
        loop.add_signal_handler(signal.SIGHUP, service.reload)  # never stops it

    with screen if screen is not None else contextlib.nullcontext():
        result = asyncio.run(
            run_simulation(
                config,
                time_scale=time_scale,
                duration_s=duration_s,
                on_tick=on_tick,
                service_hook=hook,
            )
        )
        if latest is not None:  # the last tick's frame stays on the screen
            draw(*latest)
    print_summary(result, notice)
    return 0


def print_summary(result: SimulationResult, notice: str | None = None) -> None:
    """The error tables, and what ran: ``notice`` says when it was not the config's model."""
    out = console()
    table = summary_table(result.summary)
    out.print(summary_table(result.summary, narrow=True) if too_wide(out, table) else table)
    out.print(fault_table(result.status, result.machine, result.signals))
    model = result.status["model"]
    ran = f"model {model['name']}" if model is not None else "recorded only, nothing written"
    out.print(
        f"{result.simulated_s / 3600:.2f} h simulated in {result.wall_s:.1f} s "
        f"({result.timing.ticks} ticks, {ran})"
    )
    if notice is not None:
        out.print(Text(notice, style="bold yellow"))


def _simulate_machine(args: argparse.Namespace) -> int:
    config = config_from_arg(args.config, args.overrides)
    configure_logging()
    stop = asyncio.Event()
    every = 600  # steps: a line every 10 simulated minutes at 1 s
    count = 0

    def on_step(machine: SimulatedMachine) -> None:
        nonlocal count
        count += 1
        if count % every == 0:
            truth = ", ".join(
                f"{axis} true {t:+.2f} um, offset {o:+.2f} um, compensated {c:+.2f} um"
                for axis, (t, o, c) in machine.truth_now().items()
            )
            print(f"t {machine.now_s / 3600:6.2f} h  {truth}", flush=True)

    async def main() -> SimulatedMachine:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        return await serve_machine(config, time_scale=args.time_scale, stop=stop, on_step=on_step)

    print(_start_line(config, args.time_scale), flush=True)
    machine = asyncio.run(main())
    console().print(summary_table(machine.summary()))
    plc = machine.plc
    print(f"PLC: {plc.writes} values written, heartbeat timeouts {plc.heartbeat_timeouts}")
    return 0


def _start_line(config: Config, time_scale: float) -> str:
    """What simulate-machine serves, where, and how fast: printed before the first step."""
    sim = SimulationDoc.model_validate(config.simulation or {})
    served = []
    for name, driver in config.doc.drivers.items():
        settings = driver.settings
        where = settings.get("url") or (
            f"{settings['host']}:{settings['port']}"
            if "host" in settings and "port" in settings
            else ""
        )
        served.append(f"{name} ({driver.type}{', ' + where if where else ''})")
    return (
        f"simulated machine: {sim.scenario}, {sim.hours:g} h, seed {sim.seed}, x{time_scale:g} real "
        f"time; serving {', '.join(served)}; a line every 10 simulated minutes, Ctrl-C stops"
    )


__all__ = ["register", "run_simulated"]
