"""``compd sensor trust NAME``: a person vouches for a sensor compd stands in for.

compd replaces a model input whose reading the other sensors contradict
(:mod:`compd.service.loop.plausibility`) and uses it again only on evidence:
its residue back near where it was before the episode. A sensor that was
replaced or recalibrated meanwhile may never come back there by itself; the
person who checked it says so here, and the daemon logs it.
"""

from __future__ import annotations

import argparse
from typing import Any

from compd.cli.args import daemon_options
from compd.errors import CompdError


def register(commands: Any) -> None:
    sensor = commands.add_parser(
        "sensor",
        help="a person vouches for a sensor the daemon stands in for",
        description="Sensors the other sensors contradict are replaced by their prediction "
        "until their readings are back where they were before; 'compd sensor trust NAME' "
        "ends that once a person has checked the sensor (logged by the daemon).",
    )
    actions = sensor.add_subparsers(dest="action", required=True, metavar="ACTION")
    trust = actions.add_parser(
        "trust",
        help="use NAME's readings again at its next good reading (after checking the sensor)",
    )
    trust.add_argument("name", help="the signal, as named in the config's 'signals'")
    daemon_options(trust)
    trust.set_defaults(handler=_trust)


def _trust(args: argparse.Namespace) -> int:
    import asyncio

    from compd.cli.serving import config_from_arg
    from compd.service.control.socket import request

    config = config_from_arg(args.config)
    message = {"cmd": "sensor", "trust": args.name}
    reply = asyncio.run(request(config.control_socket, message, timeout_s=5.0))
    if not reply.get("ok"):
        raise CompdError(f"the daemon refused: {reply.get('error')}")
    print(reply.get("answer"))
    return 0
