"""``compd status``: ask the running daemon over its control socket, at once.

The socket comes from two keys of the config's YAML
(:func:`compd.service.config.paths.control_socket_of`), not from validating the
whole config and its model: status must answer in a blink on an edge PC,
also to say that nothing is running. A file that is not a YAML mapping
is loaded in full, for the error that names the place.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from compd.cli.terminal import Text, console
from compd.errors import CompdError, ConfigFileError, NotRunningError
from compd.files.yamlplace import parse_yaml, read_limited, resolve_path
from compd.service.config.paths import control_socket_of
from compd.service.control.socket import request_sync


def control_socket(config_text: str) -> Path:
    """The control socket of the config ``--config`` names."""
    path = resolve_path(config_text, Path.cwd())
    text = read_limited(path, ConfigFileError).decode("utf-8", errors="replace")
    data, _ = parse_yaml(text, path, ConfigFileError)
    if not isinstance(data, dict):
        from compd.cli.serving import config_from_arg  # raises the error naming the place

        return config_from_arg(config_text).control_socket
    return control_socket_of(data, path.parent)


def status_command(args: argparse.Namespace) -> int:
    try:
        reply = request_sync(control_socket(args.config), {"cmd": "status"})
    except NotRunningError as exc:
        from compd.cli.starthint import start_hint

        raise NotRunningError(
            f"{exc}; {start_hint(resolve_path(args.config, Path.cwd()))}"
        ) from None
    if not reply.get("ok"):
        raise CompdError(f"the daemon refused: {reply.get('error')}")
    if args.json:
        print(json.dumps(reply, indent=2))
        return 0
    out = console()
    model = reply["model"]
    counters = reply["counters"]
    if model is None:
        out.print(
            Text.assemble(
                ("recording", "bold"), ": a data logger (no outputs, no model), writing nothing"
            )
        )
    else:
        out.print(
            Text.assemble((model["name"], "bold"), f"  sha256 {model['sha256'][:12]}  ")
            + f"loaded {model['loaded']}"
            + (f"  (loading {model['pending']})" if model.get("pending") else "")
        )
    if model is not None and model.get("fault"):
        out.print(Text.assemble(("model fault", "red"), f": {model['fault']}"))
    out.print(tick_line(reply))
    for name, state in reply["drivers"].items():
        if state == "not connected":  # never answered since start: a PLC off, a wrong address
            out.print(
                Text(f"driver {name} not connected: nothing read or written through it", "bold red")
            )
        elif state == "refusing writes":  # it answers, and refuses every write (an exception reply)
            out.print(
                Text(
                    f"driver {name} refusing writes: offsets and status do not reach it", "bold red"
                )
            )
    scale = reply.get("clock", {}).get("time_scale", 1)
    if scale != 1:
        virtual = scale == "max"
        note = (
            "virtual time: the times above are the machine's"
            if virtual
            else "times above are wall-clock"
        )
        out.print(
            f"clock x{scale if virtual else format(scale, 'g')}: "
            f"machine time {reply['clock']['machine_time']} ({note})"
        )
    for axis in reply["offsets_um"]:
        out.print(offset_line(axis, reply))
        envelope = reply.get("envelope", {}).get(axis)
        if envelope is not None and envelope["outside"]:
            out.print(
                Text(f"    {envelope['outside']}", "red" if envelope["faulted"] else "yellow")
            )
    for name, info in reply["inputs"].items():
        unit = f" {info['unit']}" if info.get("unit") else ""
        value = "n/a" if info["value"] is None else f"{info['value']:.3f}{unit}"
        reason = f"  {info['reason']}" if info["reason"] else ""
        out.print(f"  {name}: {value}  {info['health']}{reason}")
    for name, pair in reply.get("redundant", {}).items():
        out.print(f"  {_pair_line(name, pair)}")
    out.print(
        "  "
        + ", ".join(f"{k} {v}" for k, v in counters.items())
        + "; drivers "
        + ", ".join(f"{k} {v}" for k, v in reply["drivers"].items())
    )
    telemetry = reply.get("telemetry")
    if telemetry:
        state = Text("connected") if telemetry["connected"] else Text("not connected", "red")
        out.print(
            Text.assemble("  telemetry ", state) + f": published {telemetry['published']}, "
            f"acknowledged {telemetry['acknowledged']}, dropped {telemetry['dropped']}"
        )
        if telemetry.get("stands_by_for"):
            other = telemetry["stands_by_for"]
            out.print(Text(f"  telemetry stands by: {other} publishes as this machine_id", "red"))
    probes = reply.get("probes")
    for axis, p in ((probes or {}).get("axes") or {}).items():
        out.print(_probe_line(axis, p))
    for why in ("off", "fault"):
        if probes and probes.get(why):
            out.print(Text(f"  probe learning {why}: {probes[why]}", "red"))
    for row in reply.get("unverifiable") or []:
        if not row["verifiable"]:
            out.print(unverifiable_line(row))
    if (line := state_line(reply)) is not None:
        out.print(line)
    return 0


def state_line(reply: dict[str, Any]) -> Text | None:
    """``state not saved in DIR (error): a restart resumes from an older state``, while saves fail;
    None while they work (a daemon too old to say: None too)."""
    state = reply.get("state")
    if not state or state["saving"]:
        return None
    return Text(
        f"  state not saved in {state['directory']} ({state['error']}): "
        "a restart resumes from an older state",
        "bold red",
    )


def tick_line(reply: dict[str, Any]) -> str:
    """``last tick 0.8 s ago (...)  status word 1025 (degraded)  heartbeat 436``: the word's level in
    words, so a number is not read as all well."""
    level = reply.get("level")
    word = f"{reply['status_word']}" + ("" if level is None else f" ({level})")
    return f"last tick {_tick_age(reply)}  status word {word}  heartbeat {reply['heartbeat']}"


def offset_line(axis: str, reply: dict[str, Any]) -> str:
    """``offset Z: +0.158 um (target ...)``; ``(not written: plc link down; ...)`` while the
    last tick did not write it: the PLC then holds another offset (``offsets_held_um``)."""
    value = reply["offsets_um"][axis]
    target = reply["targets_um"].get(axis)
    sign = reply.get("signs", {}).get(axis, 1)
    why = (
        "model not started"
        if target is None
        else f"target {target:+.3f} um = sign {sign:+g} x model drift {target * sign:+.3f} um"
    )
    not_written = reply.get("offsets_not_written", {}).get(axis)
    if not_written is not None:
        why = f"not written: {not_written}; {why}"
    return f"  offset {axis}: {value:+.3f} um ({why})"


def unverifiable_line(row: dict[str, Any]) -> Text:
    """``not verifiable: T_spindle_degC 97 um on Z (add a redundant sensor / probes)``: the sensors
    cannot see a wrong reading of the input that moves the axis beyond its tolerance."""
    um = row["undetectable_um"]
    size = "any error" if um is None else f"{um:.0f} um"
    return Text(
        f"  not verifiable: {row['input']} {size} on {row['axis']} "
        f"(tolerance {row['tolerance_um']:.3g} um; {row['remedy']})",
        "yellow",
    )


def _probe_line(axis: str, probe: dict[str, Any]) -> Text:
    """One probed axis: the last probe and its innovation, what was learned, due or disagreeing."""
    last = probe.get("last")
    age = probe.get("last_taken_age_s")
    said = "no probe yet" if last is None else f"last probe {last['result']}"
    if last is not None and last.get("innovation_um") is not None:
        said += f", innovation {last['innovation_um']:+.3f} um"
    if age is not None:
        said += f", {age / 3600:.1f} h ago"
    counts = ", ".join(f"{k} {v}" for k, v in sorted(probe.get("results", {}).items()))
    line = Text(
        f"  probes {axis}: {said}; learned {probe['adjustment_um']:+.3f} um"
        + (f"; {counts}" if counts else "")
        + f"; {_shift_rms(probe)}"
    )
    if probe.get("due"):
        line.append("; probe due", "yellow")
    if probe.get("disagrees"):
        line.append("; two probes not taken: the model no longer describes the machine", "red")
    return line


def _shift_rms(probe: dict[str, Any]) -> str:
    """``probe RMS this shift 0.412 um (3 probes)``: how well compensation held on the parts."""
    rms, count = probe.get("shift_rms_um"), probe.get("shift_probes", 0)
    if rms is None:
        return "probe RMS this shift: no probe yet"
    return f"probe RMS this shift {rms:.3f} um ({count} probe{'s' if count != 1 else ''})"


def _tick_age(reply: dict[str, object]) -> str:
    """``0.8 s ago (2026-11-24T06:00:01+00:00)``, or ``none yet``."""
    age_s = reply.get("last_tick_age_s")
    if reply.get("last_tick") is None or not isinstance(age_s, int | float):
        return "none yet"
    return f"{age_s:.1f} s ago ({reply['last_tick']})"


def _pair_line(name: str, pair: dict[str, Any]) -> str:
    """A redundant pair as ``compd status`` prints it: learning, agreeing, or its fault."""
    head = f"pair {name} / {pair['partner']}"
    if pair["usual"] is None:
        return f"{head}: learning their usual difference"
    unit = pair["unit"]
    now = "" if pair["excess"] is None else f", {pair['excess']:+.3f} {unit} from it now"
    state = "agree" if pair["fault"] is None else f"FAULT ({pair['using']} used): {pair['fault']}"
    return (
        f"{head}: usual difference {pair['usual']:+.3f} {unit}{now} "
        f"(tolerance {pair['tolerance']:g}); {state}"
    )
