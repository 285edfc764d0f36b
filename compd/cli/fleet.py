"""``compd fleet list``: the machines on the fleet's MQTT broker, as their retained births and deaths say."""

from __future__ import annotations

import argparse
from typing import Any

from compd.cli.args import broker_option


def register(commands: Any) -> None:
    fleet = commands.add_parser(
        "fleet", help="the machines on the fleet's MQTT broker: model, online or offline, last seen"
    ).add_subparsers(metavar="ACTION")
    listing = fleet.add_parser(
        "list",
        help="every machine the broker holds a birth, death or desired model of",
        description="Every machine the fleet's MQTT broker holds a retained birth, death or "
        "desired record of (all of them: read until a marker published after them comes back): "
        "its host, the model it runs (name, sha256), whether it runs the fleet's desired model, "
        "online or offline (the reason its death gives), and when it was last seen. "
        "Retained messages are all it reads, so a daemon standing by for another with its "
        "machine_id (it publishes nothing) is not listed, and no probe is shown as due "
        "(no telemetry message carries one yet). The user must be allowed to write "
        "<prefix>/+/desired (the marker), as the roll-out user is. "
        "Exit status 0; 2 if the broker cannot be read.",
    )
    broker_option(listing)
    listing.add_argument(
        "--timeout-s",
        type=float,
        default=30.0,
        help="wait this long for the broker's retained messages (default 30)",
    )
    listing.add_argument("--json", action="store_true", help="print the machines as JSON")
    listing.set_defaults(handler=_list)


def _list(args: argparse.Namespace) -> int:
    from compd.cli.fleetlist import list_command

    return list_command(args)
