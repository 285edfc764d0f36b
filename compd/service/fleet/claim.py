"""One daemon per ``machine_id`` on a broker: who publishes, told by the retained birth's instance.

Two daemons configured with the same ``machine_id`` (a copied config, a test
rig left running) would both publish under ``<prefix>/<machine_id>/``: their
statuses interleave, each one's birth and death overwrite the other's, and
with one MQTT client id the broker throws each out when the other connects
(26 births and deaths in 25 s, "connection lost", the cause never named).

Each daemon's birth, death and will therefore name its :class:`Instance`
(a random id, the host, the pid, when it started), its client id is its own
(``compd-<machine_id>-<instance>``), and it subscribes to its own ``birth``
and ``death`` before it publishes anything. :class:`Claim` decides from what
it hears:

- at connect, a retained birth of another instance that is *live* (no death
  of that instance since) makes this daemon stand by: it publishes nothing,
  answers no command, and logs a fault naming the other host and pid. A
  birth from this host whose pid is gone is a crashed predecessor whose will
  the broker has not sent yet: not a rival.
- two daemons that both published (they connected at the same moment, or
  one is an older compd) hear each other's births: the one that started
  first keeps publishing (and publishes its birth again), the other stands by.
- a standby daemon whose rival dies (its death, clean or the will) takes over.
"""

from __future__ import annotations

import os
import socket
import time
import uuid
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Instance:
    """One daemon process: a random id, its host and pid, when it started (Unix s)."""

    id: str
    host: str
    pid: int
    started_unix_s: float

    @classmethod
    def this_process(cls) -> Instance:
        return cls(uuid.uuid4().hex[:16], socket.gethostname(), os.getpid(), time.time())

    def describe(self) -> dict[str, Any]:
        """The ``instance`` of a birth, death or will."""
        return {"id": self.id, "host": self.host, "pid": self.pid, "started": self.started_unix_s}


def where(instance: dict[str, Any]) -> str:
    """``host (pid N)``: how a log line names another daemon."""
    return f"{instance.get('host', '?')} (pid {instance.get('pid', '?')})"


def _pid_gone(pid: object) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # alive, another user's
        return False
    return False


@dataclass
class Claim:
    """What this daemon heard on its own ``birth`` and ``death`` topics from other instances.

    Fed from paho's thread (:meth:`heard`); :meth:`rival` says who keeps the
    ``machine_id`` from this daemon, if anyone.
    """

    me: Instance
    #: Instance id -> its newest birth and newest death heard.
    births: dict[str, dict[str, Any]] = field(default_factory=dict)
    deaths: dict[str, dict[str, Any]] = field(default_factory=dict)

    def heard(self, kind: str, payload: dict[str, Any]) -> bool:
        """Take a birth or death heard on this machine's topics; True if another instance's."""
        instance = payload.get("instance")
        key = instance.get("id") if isinstance(instance, dict) else None
        if key == self.me.id:
            return False
        key = str(key)  # "None": a compd that names no instance
        (self.births if kind == "birth" else self.deaths)[key] = payload
        return True

    def live(self) -> list[dict[str, Any]]:
        """The births of other instances not followed by their death (Sparkplug's session rule)."""
        alive = []
        for key, birth in self.births.items():
            death = self.deaths.get(key)
            if death is not None and death.get("session", 0) >= birth.get("session", 0):
                continue
            instance = birth.get("instance") or {}
            if instance.get("host") == self.me.host and _pid_gone(instance.get("pid")):
                continue  # a crashed predecessor here, its will not sent yet
            alive.append(birth)
        return alive

    def rival(self, *, publishing: bool) -> dict[str, Any] | None:
        """The other live instance that keeps the machine_id from this one, or None.

        Before publishing any live one does; while publishing only one that
        started earlier (ties: the smaller id), so of two only one stands by.
        """
        mine = (self.me.started_unix_s, self.me.id)
        for birth in self.live():
            instance = birth.get("instance") or {}
            theirs = (instance.get("started", 0.0), str(instance.get("id", "")))
            if not publishing or theirs < mine:
                return birth
        return None
