"""What ``compd run``, ``check-config`` and ``model load`` do, imported once one is chosen.

The parsers are in :mod:`compd.cli.service` and :mod:`compd.cli.model`. A
config for a real machine never loads the simulated machine, pandas or the
modelling toolkit: the twin is imported only for a config that has one.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import signal
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compd.cli.args import EXIT_NOT_CONNECTED
from compd.cli.serving import config_from_arg, configure_logging
from compd.cli.unguarded import envelope_line, load_notes, unchecked_note, unranged_note
from compd.drivers.base import address_note
from compd.drivers.registry import load_driver_type
from compd.errors import CompdError, ControlError, ModelFileError, NotRunningError
from compd.files.modelfile import load_model, model_source
from compd.files.sidecar import residual_files
from compd.files.yamlplace import read_limited
from compd.service.config.loading import Config
from compd.service.config.modelcheck import check_model
from compd.service.config.writepoints import written_points
from compd.service.control.modelload import LOAD_TIMEOUT_S, load_request, slot_from_bytes
from compd.service.control.socket import request
from compd.service.daemon import Service
from compd.service.loop.clock import RealClock
from compd.service.loop.compensator import TickRecord
from compd.service.loop.safety import Level
from compd.service.loop.signals import Health
from compd.service.notify import SystemdNotifier
from compd.service.store.state import install_model_bytes, install_sidecars, installed_model

if TYPE_CHECKING:
    from rich.console import Console

    from compd.cli.livescreen import LiveScreen
    from compd.files.modelfile import ModelFile
    from compd.model.compiled import CompiledModel
    from compd.service.config.docs import ConfigDoc
    from compd.sim.plc.machine import SimulatedMachine


def plausibility_line(model_file: ModelFile, doc: ConfigDoc) -> str:
    """What the daemon will check each model input against: the others, or each on its own."""
    consistency = model_file.consistency()
    if not doc.plausibility.enabled:
        return "plausibility: off in this config (plausibility.enabled: false): inputs checked one by one"
    if consistency is None:
        return (
            "plausibility: the model file has no consistency model (fitted before compd wrote one): "
            "inputs are checked one by one, a wrong reading within its limits is not caught; refit "
            "with compd fit to add one"
        )
    read = set(doc.signals)
    checked = [c for c in consistency.checked if c in read]
    unread = [s for s in consistency.signals if s not in read]
    line = f"plausibility: {', '.join(checked)} checked against the other signals"
    if unread:
        line += (
            f" (the calibration also logged {', '.join(unread)}, which this config does not read)"
        )
    return line


def _probe_bounds(config: Any, output: str) -> list[str]:
    """What the daemon takes of an axis's probes: one per gap, within physics, the shift a person
    accepts; and, where so, that its update starts from the default prior (the daemon logs it too)."""
    from compd.files.probeprior import output_prior
    from compd.model.proberegressors import output_columns
    from compd.model.probesettings import ProbeSettings, max_probe_um

    doc = config.doc
    probes = doc.probes
    model_file = load_model(installed_model(config.state_dir) or config.model_path)
    _, names = output_columns(model_file.compile(doc.period_s, convert=False), output)
    found = output_prior(model_file, output, names)
    prior = found.prior
    settings = ProbeSettings.defaults(
        prior, interval_s=probes.every_h * 3600.0, **probes.overrides()
    )
    line = (
        f"one taken per {probes.min_gap_s:g} s of touch time (a resend answered as it was); "
        f"|value| <= {max_probe_um(prior):g} um; the learned shift within "
        f"{settings.max_shift_um:.1f} um unless a person accepts more "
        "(compd model probe --accept-shift)"
    )
    return [line] if found.note is None else [line, f"note: {found.note}"]


def check_config_command(args: argparse.Namespace) -> int:
    from compd.cli.terminal import Text, console  # rich: not in a daemon without a terminal

    config = config_from_arg(args.config, args.overrides)
    doc = config.doc
    out = console()
    # Every check that can refuse the config runs before the first line is printed:
    # a config is "ok" or an error, never both.
    sim = _simulated_machine(config)
    probe_lines = _probe_lines(config)
    model_file = None
    if config.model_path is None:
        out.print(Text.assemble(("ok", "green"), f": {config.path}"))
        out.print(
            f"  a data logger at {doc.period_s:g} s: no outputs, no model; the signals are "
            "read, checked and recorded, nothing is written (compd record, compd run)"
        )
    else:
        # The model `compd run` would start with: the installed one, else the config's.
        installed = installed_model(config.state_dir)
        model_path = installed or config.model_path
        model_file = load_model(model_path)
        compiled = model_file.compile(doc.period_s, convert=False)  # as compd run: numpy alone
        check_model(config, model_file, compiled)
        out.print(Text.assemble(("ok", "green"), f": {config.path}"))
        out.print(
            f"  model {compiled.name} ({model_path}, sha256 {model_file.sha256[:12]}) at "
            f"{doc.period_s:g} s; outputs {', '.join(compiled.output_names)}"
            + (" (installed with 'compd model load')" if installed else "")
        )
        out.print(f"  {plausibility_line(model_file, doc)}")
        if doc.plausibility.enabled and (unchecked := unchecked_note(model_file, compiled)):
            out.print(f"  note: {unchecked}", markup=False)
        if (unranged := unranged_note(config, model_file, compiled)) is not None:
            out.print(f"  note: {unranged}", markup=False)
        _print_verifiable(out, config, model_file, compiled)
    out.print(f"  drivers: {', '.join(f'{n} ({d.type})' for n, d in doc.drivers.items())}")
    out.print(f"  signals: {', '.join(doc.signals)}")
    for pair in doc.pairs():
        out.print(
            f"  redundant: {pair.primary} and {pair.partner} read one point; beyond "
            f"{pair.tolerance:g} {pair.unit} from their usual difference (or drifting apart) "
            "the pair is a fault and the reading the other sensors support is used"
        )
    unstuck = [n for n, s in doc.signals.items() if s.checks.stuck_off(s.unit)]
    if unstuck:
        out.print(
            f"  note: no stuck detection on {', '.join(unstuck)} (a temperature gets "
            "stuck_s: 60 unless its checks say stuck_s: null; other units only where set)"
        )
    for place, note in address_notes(config):
        out.print(f"  note: {place}: {note}")
    for axis, o in doc.outputs.items():
        out.print(
            f"  axis {axis}: {o.sign:+d} x {o.model_output} -> {o.driver}:{o.address}, "
            f"|offset| <= {o.max_offset_um:g} um, <= {o.max_rate_um_per_s:g} um/s"
        )
        if model_file is not None:
            safety = doc.safety
            out.print(
                "    "
                + envelope_line(
                    model_file,
                    o.model_output,
                    safety.envelope_margin,
                    safety.envelope_after_s,
                    o.max_offset_um,
                ),
                markup=False,
            )
    for line in probe_lines:
        out.print(line)
    if sim is not None:
        out.print(
            f"  simulated machine: {sim.doc.scenario}, {sim.doc.hours:g} h, seed {sim.doc.seed}; "
            f"controllers {', '.join(f'{n} ({doc.drivers[n].type})' for n in sim.servers)}"
        )
    out.print(f"  state {config.state_dir}, recorder {config.recorder_dir or 'off'}")
    out.print(f"  control socket {config.control_socket}")
    if (t := doc.telemetry) is not None:
        scheme = "mqtts" if t.tls else "mqtt"
        out.print(
            f"  telemetry {scheme}://{t.host}:{t.broker_port} as {t.topic_prefix}/{t.machine_id}/..., "
            f"a status every {t.every_ticks} tick(s), QoS {t.qos}"
        )
    return 0


def _simulated_machine(config: Config) -> SimulatedMachine | None:
    """The simulated machine of a config with a ``simulation`` section (checked, not started)."""
    if config.simulation is None:
        return None
    from compd.sim.plc.build import build_machine  # the twin only where a config has one

    return build_machine(config)  # checks the mapping; starts nothing


def _probe_lines(config: Config) -> list[str]:
    """Per probed axis: where its probes come from and what the daemon takes of them."""
    doc = config.doc
    probes = doc.probes
    if probes is None or not probes.enabled:
        return []
    lines = []
    for axis, reg in probes.axes.items():
        where = (
            "compd model probe and the control socket only"
            if reg is None
            else f"{reg.driver}: value {reg.value_address} (x {reg.value_scale:g} um), "
            f"count {reg.counter_address}, echo {reg.echo_address}"
        )
        lines.append(f"  probes {axis}: {probes.measures}, due every {probes.every_h:g} h; {where}")
        lines += [f"    {line}" for line in _probe_bounds(config, doc.outputs[axis].model_output)]
    return lines


def _print_verifiable(
    out: Console, config: Config, model_file: ModelFile, compiled: CompiledModel
) -> None:
    """What this config's sensors cannot verify of the model: information, check-config still exits 0."""
    from compd.cli.verifytable import print_verifiable
    from compd.service.config.verifiable import config_unverifiable

    units = {name: s.unit for name, s in config.doc.signals.items()}
    print_verifiable(out, config_unverifiable(config.doc, model_file, compiled), units)


def address_notes(config: Config) -> list[tuple[str, str]]:
    """Each address a driver read in another numbering than written (Modicon 40101), with its place."""
    doc = config.doc
    places = [(f"signals.{n}.address", s.driver, s.address) for n, s in doc.signals.items()]
    places += [(".".join(map(str, loc)), d, a) for loc, d, a in written_points(doc)]
    notes = []
    for place, driver, address in places:
        note = address_note(load_driver_type(doc.drivers[driver].type), address)
        if note is not None:
            notes.append((place, note))
    return notes


def run_command(args: argparse.Namespace) -> int:
    # SIGHUP's default ends the process: ignored until the loop takes it (install_signal_handlers);
    # compd.cli.main ignores it before this module is imported, this call is for other callers.
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        return _run(args)
    finally:
        # The loop's close put SIGHUP's default back: ignored again while the process ends.
        signal.signal(signal.SIGHUP, signal.SIG_IGN)


def _run(args: argparse.Namespace) -> int:
    config = config_from_arg(args.config, args.overrides)
    json_lines = {"auto": None, "json": True, "console": False}[args.log_format]
    configure_logging(json_lines=json_lines, level=args.log_level.upper())
    live_every = args.live_every
    if config.simulation is not None:
        from compd.cli.simulate import run_simulated  # the twin only where a config has one

        return run_simulated(config, args.time_scale, args.duration_s, live_every)
    if args.time_scale is None:
        raise CompdError(
            f"--time-scale max runs on virtual time: only for a simulated machine, and "
            f"{config.path} has no 'simulation' section; give a factor such as 600"
        )
    return asyncio.run(_serve(config, args.time_scale, args.duration_s, live_every))


async def _serve(
    config: Config, time_scale: float, duration_s: float | None, live_every: int | None
) -> int:
    clock = RealClock(time_scale)
    from compd.cli.modellist import installed_notice

    if (notice := installed_notice(config)) is not None:
        from compd.cli.terminal import Text, console  # rich: only when there is a notice

        console().print(Text(notice, style="bold yellow"))
    # On a terminal with no --live-every: the live view; else a line every N ticks, if asked.
    screen = None
    if live_every is None and sys.stdout.isatty():
        from compd.cli.livescreen import LiveScreen  # rich.live: only a terminal needs it
        from compd.cli.terminal import console

        screen = LiveScreen(console())
    # The view first: the start-up's logs go to the terminal above its first frame, and
    # their warnings (a saved state ignored) to its panel too.
    with screen if screen is not None else contextlib.nullcontext():
        service = Service(config, clock=clock, notifier=SystemdNotifier())
        if screen is not None:
            service.subscribe(_live_view(service, screen, duration_s))
        elif live_every:
            service.subscribe(_live_printer(live_every, service))
        install_signal_handlers(service)
        await service.run(duration_s=duration_s)
    if duration_s is not None:
        never_connected(service, duration_s)
    return 0


class NeverConnectedError(CompdError):
    """``compd run --duration-s`` ended without any driver answering once (exit status 3)."""

    exit_status = EXIT_NOT_CONNECTED


def never_connected(service: Service, duration_s: float, what: str = "run") -> None:
    """A bounded run (a commissioning test) whose drivers never answered did not compensate: an error.

    A daemon without ``--duration-s`` runs on and reconnects (a PLC off at night);
    a run that was asked to show the compensation for a while and never reached
    the machine must not end as if it had. So must a recording (``what``): its
    rows hold no reading of the signals that driver serves.
    """
    silent = not_connected(service)
    if not silent:
        return
    links = service.links
    why = "; ".join(f"{name}: {links[name].last_error or 'no answer'}" for name in silent)
    config = service.config.path
    raise NeverConnectedError(
        f"driver {', '.join(silent)} not connected in the {duration_s:g} s {what} ({why}): "
        f"nothing was read or written through {'it' if len(silent) == 1 else 'them'}. Check "
        f"the address and that the controller is on and reachable; 'compd read --config "
        f"{config}' reads the configured points once, 'compd probe TYPE --set host=... "
        "ADDRESS' one address"
    )


def not_connected(service: Service) -> list[str]:
    """The drivers that have not answered once since start (:attr:`DriverLink.answered`)."""
    return [name for name, link in service.links.items() if not link.answered]


def _live_view(service: Service, screen: LiveScreen, duration_s: float | None) -> Any:
    """A frame at most every ``FRAME_S`` real seconds, and the last tick's at the end."""
    from rich.text import Text

    from compd.cli.livescreen import FRAME_S
    from compd.cli.tickview import level_text, progress, tick_view, too_wide

    doc = service.config.doc
    units = {name: signal.unit for name, signal in doc.signals.items()}
    signs = {axis: output.sign for axis, output in doc.outputs.items()}
    last_frame_s = -math.inf
    first_t_s: float | None = None  # the run's clock time starts at its first tick

    def show(record: TickRecord) -> None:
        nonlocal last_frame_s, first_t_s
        if first_t_s is None:
            first_t_s = record.t_s
        run_s = record.t_s - first_t_s
        now_s = time.perf_counter()
        ending = duration_s is not None and run_s + doc.period_s > duration_s
        if now_s - last_frame_s < FRAME_S and not ending:
            return
        last_frame_s = now_s
        comp = service.compensator
        head = Text.assemble(
            ("compd ", "bold"),
            f"model {comp.active.compiled.name}  {progress(run_s, duration_s)}  status ",
            level_text(record),
        )
        if silent := not_connected(service):
            head.append(f"  {', '.join(silent)} not connected", "bold red")
        counters = {
            "ticks": comp.counters.ticks,
            "signal_faults": comp.counters.signal_faults,
            "reconnects": sum(link.reconnects for link in service.links.values()),
        }
        view = tick_view(head, record, units, signs, counters)
        if too_wide(screen.console, view):  # 80 columns: two-line titles
            view = tick_view(head, record, units, signs, counters, narrow=True)
        screen.show(view)

    return show


def _live_printer(every: int, service: Service) -> Any:
    signs = {axis: output.sign for axis, output in service.config.doc.outputs.items()}
    count = 0

    def show(record: TickRecord) -> None:
        nonlocal count
        count += 1
        if count % every:
            return
        offsets = "  ".join(
            _offset_words(axis, v, record.acknowledged_um.get(axis), signs.get(axis, 1))
            for axis, v in record.offsets_um.items()
        )
        bad = [n for n, h in record.health.items() if h is not Health.OK]
        level = Level(record.status & 0b11).name.lower()
        silent = not_connected(service)
        print(
            f"t {record.t_s / 3600:7.3f} h  {offsets}  status {level}"
            + (f" ({', '.join(bad)})" if bad else "")
            + (f"  {', '.join(silent)} not connected" if silent else ""),
            flush=True,
        )

    return show


def _offset_words(axis: str, offset_um: float, acknowledged_um: float | None, sign: float) -> str:
    """``Z offset written +1.234 um (...)``, or ``not written`` where the device acknowledged nothing."""
    if acknowledged_um is None or math.isnan(acknowledged_um):
        return f"{axis} offset NOT WRITTEN (would be {offset_um:+.3f} um)"
    return f"{axis} offset written {offset_um:+8.3f} um (sign {sign:+g} x drift)"


def model_load_command(args: argparse.Namespace) -> int:
    config = config_from_arg(args.config)
    if args.previous == (args.model is not None):
        raise CompdError(
            "compd model load takes a MODEL.yaml or --previous (the model that ran before "
            "the last load; 'compd model list' shows them), not both or neither"
        )
    model = args.model
    if args.previous:
        from compd.cli.modellist import previous_or_refuse

        model = previous_or_refuse(config)
    return asyncio.run(model_load(config, model))


async def model_load(config: Config, model_path: Path) -> int:
    """``compd model load``: validate the model, send its bytes to the running daemon.

    The client reads the file (with its own rights, size-limited) and checks
    it first, for a quick message naming the file; the daemon checks it
    again and installs it. With no daemon running (no socket, or nobody
    listening on it), the client installs it for the next start. A daemon
    that runs but cannot be told (busy, no answer, no permission) is an
    error, and nothing is installed: the installed model and the running
    one never disagree.
    """
    model_path = model_source(model_path)  # bundled:NAME as `compd model check` reads it
    raw = read_limited(model_path, ModelFileError)
    slot = slot_from_bytes(config, raw, model_path, 0.0)
    # It runs, but without what the file lacks: said once it is installed or loaded.
    notes = [f"note: {n}" for n in load_notes(config, slot.model_file, slot.compiled)]
    # A stacked model's forests go with it (checked above against the file's sha256).
    sidecars = {
        f: (model_path.parent / f).read_bytes() for f in residual_files(slot.model_file.doc)
    }
    try:
        reply = await request(
            config.control_socket,
            load_request(raw, model_path, sidecars),
            timeout_s=LOAD_TIMEOUT_S + 10,
        )
    except NotRunningError as exc:
        install_sidecars(config.state_dir, sidecars)
        installed = install_model_bytes(config.state_dir, raw, config.model_path)
        if installed == config.model_path:
            print(f"{slot.compiled.name} (sha256 {slot.sha256[:12]}) is the config's own model")
        else:
            print(f"installed {slot.compiled.name} (sha256 {slot.sha256[:12]}) as {installed}")
        print(f"no daemon runs ({exc}); it will start with this model", file=sys.stderr)
        _say(notes)
        return 0
    except ControlError as exc:
        raise ControlError(
            f"{model_path} was not loaded and nothing was installed: the daemon on "
            f"{config.control_socket} was not told ({exc}); it goes on with its model. "
            "Try again ('compd status' shows what it runs)"
        ) from None
    if not reply.get("ok"):
        raise CompdError(f"the daemon refused the model: {reply.get('error')}")
    if reply.get("already_running") or reply.get("already_loading"):
        doing = "running" if reply.get("already_running") else "switching to"
        print(
            f"the daemon is already {doing} {slot.compiled.name} (sha256 {slot.sha256[:12]}): "
            "nothing loaded, no blend"
        )
        return 0
    print(f"installed {slot.compiled.name} (sha256 {slot.sha256[:12]}) as {reply.get('installed')}")
    print(f"the daemon is switching to it, blended over {reply.get('blend_s', 0):g} s")
    _say(notes)
    return 0


def _say(notes: list[str]) -> None:
    for note in notes:
        print(note, file=sys.stderr)


def install_signal_handlers(service: Service) -> None:
    """SIGTERM and SIGINT stop the service cleanly; SIGHUP re-reads its config and never stops it."""
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, service.stop)
    loop.add_signal_handler(signal.SIGHUP, service.reload)
