"""``compd run``, ``compd check-config``, ``compd status`` and ``compd model load``: the daemon's commands."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import signal
import sys
from pathlib import Path
from typing import Any

import structlog

from compd.cli.common import console
from compd.cli.simulate import run_simulated, time_scale_arg
from compd.errors import CompdError, ControlError, ModelFileError
from compd.files.modelfile import load_model
from compd.files.yamlplace import read_limited, resolve_path
from compd.service.clock import RealClock
from compd.service.compensator import TickRecord
from compd.service.config import Config, check_model, load_config
from compd.service.control import request, request_sync
from compd.service.daemon import Service
from compd.service.modelload import LOAD_TIMEOUT_S, load_request, slot_from_bytes
from compd.service.notify import SystemdNotifier
from compd.service.safety import Level
from compd.service.signals import Health
from compd.service.state import install_model_bytes, installed_model
from compd.sim.plc.build import build_machine

DEFAULT_CONFIG = Path("/etc/compd/compd.yaml")


def register(commands: Any) -> None:
    run = commands.add_parser(
        "run", help="the compensation service: read, model, limit, write at 1 Hz"
    )
    run.add_argument("--config", required=True, metavar="FILE.yaml", help="path or bundled:NAME")
    run.add_argument(
        "--time-scale",
        type=time_scale_arg,
        default=1.0,
        metavar="X|max",
        help="run the clock X times faster than real time, or 'max': virtual time, as fast as "
        "the I/O allows (simulated machines only; default 1)",
    )
    run.add_argument(
        "--duration-s",
        type=float,
        metavar="S",
        help="stop cleanly after S seconds of (scaled) clock time, saving state",
    )
    run.add_argument(
        "--live-every",
        type=int,
        metavar="N",
        help="print a live line every N ticks (default: the config's live_every_ticks, "
        "on a terminal only)",
    )
    run.add_argument(
        "--log-format",
        choices=("auto", "json", "console"),
        default="auto",
        help="JSON lines (journald) or human-readable; auto: human-readable on a terminal",
    )
    run.set_defaults(handler=_run)

    check = commands.add_parser(
        "check-config", help="validate a daemon config and its model exactly as 'compd run' does"
    )
    check.add_argument("config", metavar="FILE.yaml")
    check.set_defaults(handler=_check_config)

    status = commands.add_parser(
        "status", help="the running daemon's model, inputs, offsets, counters"
    )
    _daemon_options(status)
    status.add_argument("--json", action="store_true", help="print the daemon's JSON reply")
    status.set_defaults(handler=_status)


def register_model_load(model_actions: Any) -> None:
    """``compd model load``, added to the ``model`` group of :mod:`compd.cli.evaluate`."""
    load = model_actions.add_parser(
        "load", help="validate, install and switch the running daemon to a model file"
    )
    load.add_argument("model", type=Path, metavar="MODEL.yaml")
    _daemon_options(load)
    load.set_defaults(handler=_model_load)


def _daemon_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        default=str(DEFAULT_CONFIG),
        metavar="FILE.yaml",
        help=f"the daemon's config (default {DEFAULT_CONFIG}); gives the state dir and socket",
    )


def _config(text: str) -> Config:
    return load_config(resolve_path(text, Path.cwd()))


def _check_config(args: argparse.Namespace) -> int:
    config = _config(args.config)
    # The model `compd run` would start with: the installed one, else the config's.
    installed = installed_model(config.state_dir)
    model_path = installed or config.model_path
    model_file = load_model(model_path)
    compiled = model_file.compile(config.doc.period_s)
    check_model(config, model_file, compiled)
    doc = config.doc
    out = console()
    out.print(f"[green]ok[/green]: {config.path}")
    out.print(
        f"  model {compiled.name} ({model_path}, sha256 {model_file.sha256[:12]}) at "
        f"{doc.period_s:g} s; outputs {', '.join(compiled.output_names)}"
        + (" (installed with 'compd model load')" if installed else "")
    )
    out.print(f"  drivers: {', '.join(f'{n} ({d.type})' for n, d in doc.drivers.items())}")
    out.print(f"  signals: {', '.join(doc.signals)}")
    for axis, o in doc.outputs.items():
        out.print(
            f"  axis {axis}: {o.sign:+d} x {o.model_output} -> {o.driver}:{o.address}, "
            f"|offset| <= {o.max_offset_um:g} um, <= {o.max_rate_um_per_s:g} um/s"
        )
    if config.simulation is not None:
        sim = build_machine(config)  # checks the mapping; starts nothing
        out.print(
            f"  simulated machine: {sim.doc.scenario}, {sim.doc.hours:g} h, seed {sim.doc.seed}; "
            f"controllers {', '.join(f'{n} ({doc.drivers[n].type})' for n in sim.servers)}"
        )
    out.print(f"  state {config.state_dir}, recorder {config.recorder_dir or 'off'}")
    out.print(f"  control socket {config.control_socket}")
    return 0


def _run(args: argparse.Namespace) -> int:
    config = _config(args.config)
    json_lines = {"auto": None, "json": True, "console": False}[args.log_format]
    configure_logging(json_lines=json_lines)
    live_every = args.live_every
    if config.simulation is not None:
        return run_simulated(config, args.time_scale, args.duration_s, live_every)
    if args.time_scale is None:
        raise CompdError(
            f"--time-scale max runs on virtual time: only for a simulated machine, and "
            f"{config.path} has no 'simulation' section; give a factor such as 600"
        )
    if live_every is None and sys.stdout.isatty():
        live_every = config.doc.live_every_ticks
    return asyncio.run(_serve(config, args.time_scale, args.duration_s, live_every))


async def _serve(
    config: Config, time_scale: float, duration_s: float | None, live_every: int | None
) -> int:
    clock = RealClock(time_scale)
    live = _live_printer(live_every) if live_every else None
    service = Service(config, clock=clock, notifier=SystemdNotifier(), on_tick=live)
    install_signal_handlers(service)
    await service.run(duration_s=duration_s)
    return 0


def _live_printer(every: int) -> Any:
    count = 0

    def show(record: TickRecord) -> None:
        nonlocal count
        count += 1
        if count % every:
            return
        offsets = "  ".join(f"{axis} {v:+8.3f} um" for axis, v in record.offsets_um.items())
        bad = [n for n, h in record.health.items() if h is not Health.OK]
        level = Level(record.status & 0b11).name.lower()
        print(
            f"t {record.t_s / 3600:7.3f} h  {offsets}  status {level}"
            + (f" ({', '.join(bad)})" if bad else ""),
            flush=True,
        )

    return show


def _ask(config_text: str, message: dict[str, Any]) -> tuple[Config, dict[str, Any]]:
    config = _config(config_text)
    return config, request_sync(config.control_socket, message)


def _status(args: argparse.Namespace) -> int:
    _, reply = _ask(args.config, {"cmd": "status"})
    if not reply.get("ok"):
        raise CompdError(f"the daemon refused: {reply.get('error')}")
    if args.json:
        print(json.dumps(reply, indent=2))
        return 0
    out = console()
    model = reply["model"]
    counters = reply["counters"]
    out.print(
        f"[bold]{model['name']}[/bold]  sha256 {model['sha256'][:12]}  loaded {model['loaded']}"
        + (f"  (loading {model['pending']})" if model.get("pending") else "")
    )
    if model.get("fault"):
        out.print(f"[red]model fault[/red]: {model['fault']}")
    out.print(
        f"last tick {reply['last_tick']}  status word {reply['status_word']}  "
        f"heartbeat {reply['heartbeat']}"
    )
    for axis, value in reply["offsets_um"].items():
        target = reply["targets_um"].get(axis)
        model = "not started" if target is None else f"{target:+.3f} um"
        out.print(f"  offset {axis}: {value:+.3f} um (model {model})")
    for name, info in reply["inputs"].items():
        value = "n/a" if info["value"] is None else f"{info['value']:.3f}"
        reason = f"  {info['reason']}" if info["reason"] else ""
        out.print(f"  {name}: {value}  {info['health']}{reason}")
    out.print(
        "  "
        + ", ".join(f"{k} {v}" for k, v in counters.items())
        + "; drivers "
        + ", ".join(f"{k} {v}" for k, v in reply["drivers"].items())
    )
    return 0


def _model_load(args: argparse.Namespace) -> int:
    return asyncio.run(model_load(_config(args.config), args.model))


async def model_load(config: Config, model_path: Path) -> int:
    """``compd model load``: validate the model, send its bytes to the running daemon.

    The client reads the file (with its own rights, size-limited) and checks
    it first, for a quick message naming the file; the daemon checks it
    again and installs it. With no daemon running, the client installs it
    for the next start.
    """
    raw = read_limited(model_path, ModelFileError)
    slot = slot_from_bytes(config, raw, model_path, 0.0)
    try:
        reply = await request(
            config.control_socket, load_request(raw, model_path), timeout_s=LOAD_TIMEOUT_S + 10
        )
    except ControlError as exc:
        installed = install_model_bytes(config.state_dir, raw)
        print(f"installed {slot.compiled.name} (sha256 {slot.sha256[:12]}) as {installed}")
        print(f"the daemon was not told ({exc}); it will start with this model", file=sys.stderr)
        return 0
    if not reply.get("ok"):
        raise CompdError(f"the daemon refused the model: {reply.get('error')}")
    print(f"installed {slot.compiled.name} (sha256 {slot.sha256[:12]}) as {reply.get('installed')}")
    print(f"the daemon is switching to it, blended over {reply.get('blend_s', 0):g} s")
    return 0


def configure_logging(*, json_lines: bool | None = None, level: str = "INFO") -> None:
    """structlog: JSON lines (stdout, journald) by default, human-readable on a terminal.

    Standard-library loggers (the control socket, the recorder) go through the same renderer.
    """
    if json_lines is None:
        json_lines = not sys.stdout.isatty()
    shared: list[Any] = [
        structlog.stdlib.add_log_level,
        structlog.stdlib.add_logger_name,
        structlog.processors.TimeStamper(fmt="iso", utc=True),
    ]
    renderer: Any = (
        structlog.processors.JSONRenderer() if json_lines else structlog.dev.ConsoleRenderer()
    )
    structlog.configure(
        processors=[*shared, structlog.stdlib.ProcessorFormatter.wrap_for_formatter],
        logger_factory=structlog.stdlib.LoggerFactory(),
        wrapper_class=structlog.stdlib.BoundLogger,
        # Not cached: compd logs once per fault episode, so the lookup costs nothing, and a
        # cached module-level logger would ignore any later configuration (tests' capture_logs).
        cache_logger_on_first_use=False,
    )
    formatter = structlog.stdlib.ProcessorFormatter(
        foreign_pre_chain=shared,
        processors=[structlog.stdlib.ProcessorFormatter.remove_processors_meta, renderer],
    )
    handler = logging.StreamHandler(sys.stdout)
    handler.setFormatter(formatter)
    root = logging.getLogger()
    root.handlers = [handler]
    root.setLevel(level)


def install_signal_handlers(service: Service) -> None:
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, service.stop)
