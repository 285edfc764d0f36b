"""``compd model probe``: a probe, gauge or CMM result for an axis, given to the running daemon.

What a person measured on a part or a datum (um) and when (default: now):
the daemon takes it at its next tick as it takes a PLC's probe cycle
(:mod:`compd.service.loop.probing`) and answers with what the update did.
``--reset`` returns the running model to the calibration's parameters.

The daemon takes each probe once: the same probe sent again (a retry with
the same ``--at``) is answered with what it did the first time, and one
touched within ``probes.min_gap_s`` of the last is refused. An update that
would move the learned adjustment beyond ``probes.max_shift_um`` is not
applied; ``--accept-shift`` is a person saying the machine did move.
"""

from __future__ import annotations

import argparse
import datetime as dt
from typing import Any

from compd.cli.args import daemon_options
from compd.errors import CompdError


def register(model: Any) -> None:
    """The ``probe`` action of ``compd model``."""
    probe = model.add_parser(
        "probe",
        help="give the running daemon a probe or gauge result for an axis (or --reset)",
        description="Send AXIS's measured value (um) to the running daemon, which updates its "
        "model's parameters with it (config 'probes'). With compensation active a probe "
        "sees the residue (what is left on the part); --measures thermal_error for a "
        "value measured without compensation.",
    )
    probe.add_argument("axis", nargs="?", help="the axis measured (a name under 'outputs')")
    probe.add_argument("measured_um", nargs="?", type=float, help="the measured value, um")
    probe.add_argument(
        "--at",
        metavar="TIME",
        help="when the probe touched: ISO 8601 (2026-11-28T09:30:00+00:00) or unix s; default now",
    )
    probe.add_argument(
        "--measures",
        choices=("residue", "thermal_error"),
        help="what the value is (default: the config's probes.measures)",
    )
    probe.add_argument(
        "--accept-shift",
        action="store_true",
        help="the machine did move (a crash, a re-clamped fixture): take the probe even where it "
        "moves the learned adjustment beyond probes.max_shift_um, without waiting for a "
        "confirming probe",
    )
    probe.add_argument(
        "--reset",
        action="store_true",
        help="forget what the probes taught: the calibration's parameters again",
    )
    daemon_options(probe)
    probe.set_defaults(handler=_probe)


def touched_at(text: str) -> float:
    """Unix s from ``--at``: a number, or an ISO 8601 time (one without a zone is UTC)."""
    try:
        return float(text)
    except ValueError:
        pass
    try:
        when = dt.datetime.fromisoformat(text)
    except ValueError:
        raise CompdError(
            f"--at {text!r} is not a time: give ISO 8601 (2026-11-28T09:30:00+00:00) or unix s"
        ) from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.UTC)
    return when.timestamp()


def probe_message(args: argparse.Namespace) -> dict[str, Any]:
    """The control socket's ``probe`` request for the command line."""
    if args.reset:
        if args.axis is not None or args.accept_shift:
            raise CompdError("compd model probe --reset takes no axis, value or --accept-shift")
        return {"cmd": "probe", "reset": True}
    if args.axis is None or args.measured_um is None:
        raise CompdError("compd model probe needs AXIS and MEASURED_UM (or --reset)")
    message: dict[str, Any] = {"cmd": "probe", "axis": args.axis, "measured_um": args.measured_um}
    message["source"] = "cli"
    if args.at is not None:
        message["touched_at_unix_s"] = touched_at(args.at)
    if args.measures is not None:
        message["measures"] = args.measures
    if args.accept_shift:
        message["accept_shift"] = True
    return message


def _probe(args: argparse.Namespace) -> int:
    import asyncio

    from compd.cli.serving import config_from_arg
    from compd.service.control.socket import request

    message = probe_message(args)
    config = config_from_arg(args.config)
    reply = asyncio.run(request(config.control_socket, message, timeout_s=15.0))
    if not reply.get("ok"):
        raise CompdError(f"the daemon refused the probe: {reply.get('error')}")
    if reply.get("reset"):
        print("probe updates reset: the running model has the calibration's parameters again")
        return 0
    if not reply.get("taken"):
        print(f"queued for axis {reply.get('axis')}: the daemon takes it at its next tick")
        return 0
    last = reply.get("last") or {}
    result = last.get("result")
    if result == "duplicate":
        print(f"{args.axis}: {last.get('reason')}")
        return 0
    line = f"{args.axis}: {result}"
    if last.get("innovation_um") is not None:
        line += (
            f", innovation {last['innovation_um']:+.3f} um "
            f"(after the update {last['innovation_after_um']:+.3f} um)"
        )
    if last.get("reason"):
        line += f": {last['reason']}"
    line += (
        f"; the model's output now {reply.get('adjustment_um', 0.0):+.3f} um from the calibration's"
    )
    print(line)
    return 0 if result not in ("refused", "too_soon") else 1
