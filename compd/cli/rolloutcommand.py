"""The ``compd model rollout`` command: whom to send to, in which waves, and the table (or JSON).

Sending and answers: :mod:`compd.cli.rollout`; ``--pending`` and ``--online``
(what the broker retains): :mod:`compd.cli.rolloutpending`.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path
from typing import Any

from compd.cli.rollout import Outcome, broker_section, rollout
from compd.cli.rolloutpending import online, pending
from compd.errors import CompdError, ModelFileError
from compd.files.yamlplace import read_limited
from compd.service.config.fleetdoc import TelemetryDoc
from compd.service.fleet.remoteload import REQUEST_ID


def in_waves(
    section: TelemetryDoc, base_dir: Path, raw: bytes, name: str, machines: list[str], args: Any
) -> list[Outcome]:
    """The first ``--canary N`` machines, then the rest unless one of the canaries failed."""
    canary = max(0, args.canary or 0)
    waves = [machines[:canary], machines[canary:]] if canary else [machines]
    outcomes: list[Outcome] = []
    for k, wave in enumerate(w for w in waves if w):
        got = rollout(
            section, base_dir, raw, name, wave, timeout_s=args.timeout_s, wait_blend=args.wait_blend
        )
        outcomes += got
        failed = next((o for o in got if not o.ok), None)
        if failed is not None and k == 0 and canary:
            why = f"not sent: canary {failed.machine_id} {failed.result.replace('_', ' ')}"
            outcomes += [Outcome(m, "not_sent", reason=why) for m in machines[canary:]]
            break
    return outcomes


def machine_list(text: str | None) -> list[str]:
    """``--machines``: ``M1,M2``, or ``@FILE`` with one machine_id a line (``#`` comments)."""
    if not text:
        return []
    if text.startswith("@"):
        path = Path(text[1:])
        try:
            lines = path.read_text().splitlines()
        except OSError as exc:
            raise CompdError(f"--machines {text}: cannot read {path} ({exc.strerror})") from exc
        names = [line.split("#", 1)[0].strip() for line in lines]
    else:
        names = [m.strip() for m in text.split(",")]
    machines = [m for m in names if m]
    for machine in machines:
        if not REQUEST_ID.match(machine):
            raise CompdError(
                f"--machines: {machine!r} is not a machine_id (letters, digits, _ . : -)"
            )
    return machines


def rollout_command(args: Any) -> int:
    """The handler of ``compd rollout`` (and ``compd model rollout``): check, send, wait, print the table (or JSON)."""
    from rich.table import Table
    from rich.text import Text

    from compd.cli.terminal import console
    from compd.files.modelfile import load_model
    from compd.files.sidecar import residual_files

    section, base_dir = broker_section(args.broker_config)
    machines = machine_list(args.machines)
    if args.online:
        machines += [m for m in online(section, base_dir, args.timeout_s) if m not in machines]
    if args.pending:
        title = "pending roll-outs"
        outcomes = pending(
            section, base_dir, machines, timeout_s=args.timeout_s, wait_blend=args.wait_blend
        )
    else:
        if args.model is None or not machines:
            raise CompdError(
                "give MODEL.yaml and --machines or --online (none online?), "
                "or --pending to finish earlier roll-outs"
            )
        raw = read_limited(args.model, ModelFileError)
        if not args.no_local_check:
            model_file = load_model(args.model)
            forests = residual_files(model_file.doc)
            if forests:
                # The desired record and the command carry the YAML alone: every machine
                # would refuse it.
                raise ModelFileError(
                    args.model,
                    f"a stacked model: its residual forest ({', '.join(forests)}) does not "
                    "travel with a roll-out, so every machine would refuse it",
                    fix=f"Load it on each machine with 'compd model load {args.model}' (which "
                    "sends the .npz), or roll out the model without its forest",
                )
            model_file.compile(None)
            for finding in model_file.check_plausible():
                print(finding.describe(), file=sys.stderr)
        name = os.path.basename(args.model)
        title = f"{args.model} (sha256 {hashlib.sha256(raw).hexdigest()[:12]}) to {len(machines)}"
        outcomes = in_waves(section, base_dir, raw, name, machines, args)
    if args.json:
        rows = [vars(o) | {"ok": o.ok} for o in outcomes]
        print(json.dumps({"title": title, "machines": rows}, indent=1))
        return 0 if all(o.ok for o in outcomes) else 1
    if not outcomes:  # --pending: the broker holds no desired record (of these machines)
        which = f" for {', '.join(machines)}" if machines else ""
        console().print(
            f"no desired models pending{which}: the broker holds no roll-out's desired record "
            "(compd rollout MODEL.yaml --machines ... leaves one per machine)"
        )
        return 0
    table = Table("machine", "result", "reason", "blend (s)", "blended in", "broker says")
    for o in outcomes:
        blended = {None: "-", True: "yes", False: "not yet"}[o.blended_in]
        blend = "-" if o.blend_s is None else f"{o.blend_s:g}"
        result = Text(o.result.replace("_", " "), style="green" if o.ok else "red")
        table.add_row(o.machine_id, result, o.reason, blend, blended, o.presence)
    out = console()
    out.print(title)
    out.print(table)
    return 0 if all(o.ok for o in outcomes) else 1
