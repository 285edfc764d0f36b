"""``compd fleet list``'s work: one row per machine from the broker's retained births, deaths and desired records.

Each machine's state follows Sparkplug's rule (:func:`compd.cli.fleetstate.presence`):
``online`` while its newest birth's session is newer than its newest death's,
else ``offline`` with the death's reason (``stopped``: a clean stop;
``connection lost``: the broker sent its last will). When it was last seen:
online, now (the broker holds its connection); stopped, the death's time;
connection lost, some time after the birth of that connection (the will is
stamped when the connection is made, the broker does not stamp it).
"""

from __future__ import annotations

import datetime
import json
import time
from dataclasses import asdict, dataclass
from typing import Any

from compd.cli.fleetstate import Listener, presence
from compd.service.fleet.remoteload import DESIRED


@dataclass
class Machine:
    """One row of ``compd fleet list``."""

    machine_id: str
    #: ``online``, ``offline`` or ``never seen`` (a desired record only).
    state: str
    #: An offline machine's death: ``stopped`` or ``connection lost``.
    reason: str | None
    host: str | None
    pid: int | None
    compd_version: str | None
    model: str | None
    sha256: str | None
    #: The fleet's desired model (its sha256), and whether the machine's birth says it runs it.
    desired_sha256: str | None
    runs_desired: bool | None
    #: Unix s: now for an online machine, a clean stop's time; None if not known.
    last_seen_unix_s: float | None
    #: Unix s: the birth of the session it was last seen in (a lost connection: seen after it).
    since_unix_s: float | None


def machines(listener: Listener, now_unix_s: float) -> list[Machine]:
    """A row per machine heard of, sorted by machine_id."""
    names = set(listener.machines_heard("birth")) | set(listener.machines_heard("death"))
    names |= set(listener.machines_heard(DESIRED))
    return [_row(listener, name, now_unix_s) for name in sorted(names)]


def _row(listener: Listener, name: str, now_unix_s: float) -> Machine:
    births, deaths = listener.of(name, "birth"), listener.of(name, "death")
    desired = listener.of(name, DESIRED)
    birth = births[-1] if births else {}
    where = presence(listener, name)
    state, _, why = where.partition(" (")
    reason = why.rstrip(")") or None
    instance = birth.get("instance") or {}
    model = birth.get("model") or {}
    desired_sha = desired[-1].get("sha256") if desired else None
    since = _number(birth.get("time"))
    if state == "online":
        last_seen: float | None = now_unix_s
    elif reason == "stopped" and deaths:
        last_seen = _number(deaths[-1].get("time"))
    else:
        last_seen = None
    return Machine(
        machine_id=name,
        state=state,
        reason=reason,
        host=instance.get("host"),
        pid=instance.get("pid"),
        compd_version=birth.get("compd_version"),
        model=model.get("name"),
        sha256=model.get("sha256"),
        desired_sha256=desired_sha if isinstance(desired_sha, str) else None,
        runs_desired=None
        if desired_sha is None or not births
        else model.get("sha256") == desired_sha,
        last_seen_unix_s=last_seen,
        since_unix_s=since,
    )


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _when(unix_s: float | None) -> str:
    if unix_s is None:
        return "-"
    return datetime.datetime.fromtimestamp(unix_s, datetime.UTC).strftime("%Y-%m-%d %H:%M:%SZ")


#: A stamp this far ahead of the clock reading it was not taken on a real clock.
AHEAD_S = 300.0


def last_seen(row: Machine, now_unix_s: float | None = None) -> str:
    """The table's ``last seen``: now, a time, or after the birth of the lost connection.

    A time ahead of ``now_unix_s`` (by :data:`AHEAD_S`) came from a daemon's
    simulated clock (``--time-scale``: daemons that stamped births and deaths
    with it, before they took the real clock's time): marked so, not shown as
    a time to trust.
    """
    if row.state == "online":
        return "now"
    stamp = row.last_seen_unix_s if row.last_seen_unix_s is not None else row.since_unix_s
    if stamp is None:
        return "-"
    said = _when(stamp) if row.last_seen_unix_s is not None else f"after {_when(stamp)}"
    if now_unix_s is not None and stamp > now_unix_s + AHEAD_S:
        said += " (a simulated clock's, ahead of this one)"
    return said


def list_command(args: Any) -> int:
    """The handler of ``compd fleet list``: read the retained state, print the table (or JSON)."""
    from rich.table import Table
    from rich.text import Text

    from compd.cli.rollout import broker_section
    from compd.cli.rolloutpending import retained
    from compd.cli.terminal import console

    section, base_dir = broker_section(args.broker_config)
    listener = retained(section, base_dir, args.timeout_s)
    now_unix_s = time.time()
    rows = machines(listener, now_unix_s)
    if args.json:
        print(json.dumps({"machines": [asdict(row) for row in rows]}, indent=1))
        return 0
    table = Table("machine", "host", "model", "sha256", "desired", "state", "last seen")
    styles = {"online": "green", "offline": "red"}
    for row in rows:
        desired = {None: "-", True: "runs it", False: f"not run: {str(row.desired_sha256)[:12]}"}
        state = row.state + (f" ({row.reason})" if row.reason else "")
        table.add_row(
            row.machine_id,
            row.host or "-",
            row.model or "-",
            (row.sha256 or "-")[:12],
            desired[row.runs_desired],
            Text(state, style=styles.get(row.state, "")),
            last_seen(row, now_unix_s),
        )
    online = sum(row.state == "online" for row in rows)
    out = console()
    out.print(f"{len(rows)} machines on {section.host}:{section.broker_port}, {online} online")
    out.print(table)
    return 0
