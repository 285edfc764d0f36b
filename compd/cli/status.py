"""``compd status``: ask the running daemon over its control socket, at once.

The socket comes from two keys of the config's YAML
(:func:`compd.service.paths.control_socket_of`), not from validating the
whole config and its model: status must answer in a blink on an edge PC,
also to say that nothing is running. A file that is not a YAML mapping
is loaded in full, for the error that names the place.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from compd.cli.terminal import console
from compd.errors import CompdError, ConfigFileError
from compd.files.yamlplace import parse_yaml, read_limited, resolve_path
from compd.service.control import request_sync
from compd.service.paths import control_socket_of


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
    reply = request_sync(control_socket(args.config), {"cmd": "status"})
    if not reply.get("ok"):
        raise CompdError(f"the daemon refused: {reply.get('error')}")
    if args.json:
        print(json.dumps(reply, indent=2))
        return 0
    out = console()
    model = reply["model"]
    counters = reply["counters"]
    if model is None:
        out.print("[bold]recording[/bold]: a data logger (no outputs, no model), writing nothing")
    else:
        out.print(
            f"[bold]{model['name']}[/bold]  sha256 {model['sha256'][:12]}  "
            f"loaded {model['loaded']}"
            + (f"  (loading {model['pending']})" if model.get("pending") else "")
        )
    if model is not None and model.get("fault"):
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
    telemetry = reply.get("telemetry")
    if telemetry:
        state = "connected" if telemetry["connected"] else "[red]not connected[/red]"
        out.print(
            f"  telemetry {state}: published {telemetry['published']}, "
            f"acknowledged {telemetry['acknowledged']}, dropped {telemetry['dropped']}"
        )
    return 0
