"""Models rolled out over the broker: ``cmd/model_load`` in, the same load as the control socket's.

``compd model rollout`` publishes, to each machine's
``<prefix>/<machine_id>/cmd/model_load`` (QoS 1, not retained), a JSON
object::

    {"schema": "compd.model_load/1", "request_id": "...", "name": "twin-z.yaml",
     "model_base64": "...", "sha256": "<hex of the model file's bytes>",
     "requested_by": "who@where", "sent_unix_s": 1790000000.0}

A daemon whose telemetry section says ``accept_models: true`` (off by
default) takes it through :meth:`compd.service.daemon.Service.load_model`,
the control socket's ``load``: the same checks, install, blend and refusal,
off the tick. It answers on ``<prefix>/<machine_id>/reply/<request_id>``
with ``result``: ``accepted`` (with ``blend_s``), ``already_running`` /
``already_loading`` (nothing loaded, no blend) or ``refused`` (with
``reason``, the running model untouched); the ``model_switched`` event and
the re-birth naming the new sha256 then tell that it is switched in.

Who may send is the broker's business: each machine logs in as its own user,
and the broker's ACL lets only the roll-out user write ``<prefix>/+/cmd/#``
(deploy/README.md, "The MQTT broker"). Here the payload is bounded (a model file's
:data:`~compd.files.yamlplace.MAX_YAML_BYTES`, base64) and must carry the
sha256 of the bytes it delivers, so a truncated or altered model is refused
before it is parsed.

A command is taken once, as sent, and only fresh: a retained message (the
broker's retained store hands it out again on every connection, rolling later
roll-outs back), a ``request_id`` seen before (a replay; the ids are kept in
the state directory, :mod:`compd.service.fleet.seenrequests`) and a request sent
more than :data:`~compd.service.fleet.seenrequests.WINDOW_S` from the machine's
clock (or without ``sent_unix_s``) are refused, and the reply says which. So
is a request holding a number compd does not read (NaN, Infinity, 1e400, an
integer of more than :data:`MAX_DIGITS` digits), wherever it stands; any other
failure while checking it is answered ``refused`` as well, never left unanswered.
The broker itself drops a payload larger than the daemon's MQTT maximum packet
size (:meth:`compd.service.fleet.telemetry.Telemetry.listen`) before it is sent.

A machine away during a roll-out misses its command; the roll-out's retained
record on ``<prefix>/<machine_id>/desired`` (the same model and sha256) is
taken instead, when the daemon hears it at connecting and runs another model
(:meth:`RemoteLoads.take_desired`): checked as a command is, but for its age
and id, since the record is the fleet's current word, not a message in flight.
"""

from __future__ import annotations

import asyncio
import hashlib
import math
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable
from typing import Any

import structlog

from compd.errors import CompdError
from compd.faultlog import Event, EventSink
from compd.files.yamlplace import MAX_YAML_BYTES, shorten
from compd.service.control.modelload import load_request, request_bytes
from compd.service.fleet.seenrequests import SeenRequests
from compd.service.fleet.wirecheck import REQUEST_ID, Parsed, Parser, cheap_request_id

__all__ = ["REQUEST_ID", "RemoteLoads", "checked_request"]

log = structlog.get_logger("compd.service.fleet.remoteload")

_RETAINED = (
    "a retained command (the broker's retained store hands it out on every connection): "
    "commands are taken only as sent. Clear it: publish an empty retained message to "
    "its topic (mosquitto_pub -r -n -t TOPIC)"
)

SCHEMA = "compd.model_load/1"
#: The command's topic level: ``<prefix>/<machine_id>/cmd/model_load``.
COMMAND = "model_load"
#: ``<prefix>/<machine_id>/desired`` (retained, written by the roll-out user only): the model a
#: roll-out left for the machine, taken by :meth:`RemoteLoads.take_desired` when heard at connecting.
DESIRED = "desired"
DESIRED_SCHEMA = "compd.desired_model/1"
#: The largest payload read: a model file at its size limit, base64-encoded, and the rest.
MAX_PAYLOAD_BYTES = 4 * (MAX_YAML_BYTES // 3 + 1) + 4096
#: Digests of the payloads taken lately, kept in memory: the same bytes again are a replay,
#: answered without parsing them (the ids in the state directory catch it after a restart).
KEEP_DIGESTS = 1000

Load = Callable[[dict[str, Any]], Awaitable[dict[str, Any]]]
Reply = Callable[[str, dict[str, Any]], object]


class RemoteLoads:
    """Handles ``cmd/model_load`` payloads: ``load`` is ``Service.load_model``, ``reply`` publishes."""

    def __init__(
        self,
        load: Load,
        reply: Reply,
        events: EventSink,
        *,
        seen: SeenRequests | None = None,
        now: Callable[[], float] = time.time,
        installed: Callable[[str], bool] = lambda sha256: False,
    ) -> None:
        self.load = load
        self.reply = reply
        self.events = events
        #: The ids taken lately (the state directory's file; in memory without one).
        self.seen = seen or SeenRequests(None)
        #: The machine's real clock (the sender's ``sent_unix_s`` is real time, also in a simulation).
        self.now = now
        #: Whether a model of this sha256 was installed here before (the state directory's models).
        self.installed = installed
        self._saving = asyncio.Lock()
        #: The sha256 of desired records refused (not tried again at each reconnection).
        self._refused_desired: set[str] = set()
        #: Messages are parsed in a worker thread, one at a time.
        self.parser = Parser()
        #: The digest of each request's bytes taken lately -> its request id (a replay is refused unparsed).
        self._taken: OrderedDict[bytes, str] = OrderedDict()

    async def handle(self, payload: bytes, *, retained: bool = False) -> None:
        """Check, parse and load one request; answer it (a request without a usable id: log only).

        What can be judged from the bytes comes first, before any parse: a
        retained message (the broker's retain flag) is refused, and so are the
        very bytes of a request taken before (a replay: its sha256) and a
        request naming an id taken before (read from the bytes). The parse
        then runs in a worker thread (:class:`~compd.service.fleet.wirecheck.Parser`).
        """
        digest = hashlib.sha256(payload).digest()
        named = cheap_request_id(payload)
        replayed = digest in self._taken or (named is not None and self.seen.seen(named))
        if retained or replayed:
            request_id = self._taken.get(digest) or named
            reason = (
                _RETAINED
                if retained
                else f"request_id {request_id} was taken before: a replay, not loaded again"
            )
            self._refuse_early(request_id, reason)
            return
        try:
            parsed = await self.parser.parse(payload)
            request = checked_request(parsed)
        except CompdError as exc:
            self._refuse_early(cheap_request_id(payload), str(exc))
            return
        request_id = request["request_id"]
        by = shorten(str(request.get("requested_by", "?")), 200)
        sha256 = request.get("sha256")
        answer: dict[str, Any] = {
            "request_id": request_id,
            "sha256": sha256 if isinstance(sha256, str) else None,
        }
        try:
            if parsed.unread is not None:
                raise CompdError(f"the request holds a number compd does not read: {parsed.unread}")
            await self._admit(request)
            self._remember(digest, request_id)
            answer |= await self._load(request, by)
        except CompdError as exc:
            self._refuse(answer, str(exc), by)
        except Exception as exc:  # a bug must not leave the sender without an answer
            log.exception("remote model load failed", request_id=request_id)
            self._refuse(answer, f"the daemon failed to check it ({type(exc).__name__})", by)
        self.reply(request_id, answer)

    def _refuse_early(self, request_id: str | None, reason: str) -> None:
        """A request refused before it was parsed or read whole: one log line, an event, an answer if it names an id."""
        log.error("remote model load refused", reason=reason, request_id=request_id)
        self.events(
            Event(
                "model_refused",
                "remote model load refused",
                {"reason": reason, "request_id": request_id},
            )
        )
        if request_id is not None:
            self.reply(
                request_id,
                {"request_id": request_id, "sha256": None, "result": "refused", "reason": reason},
            )

    def _remember(self, digest: bytes, request_id: str) -> None:
        self._taken[digest] = request_id
        while len(self._taken) > KEEP_DIGESTS:
            self._taken.popitem(last=False)

    async def take_desired(self, payload: bytes) -> None:
        """Load the roll-out's desired record, heard at connecting: a machine that was away catches up.

        The record is the fleet's current word (each roll-out overwrites it,
        and only the roll-out user may write it: docs/fleet.md, "Rolling a model out"), so
        neither its age nor its id is checked as a command's are; everything
        else is: its sha256, then the daemon's own checks, blend or refusal
        (a ``model_refused`` event; a record refused once is not tried again
        by this process). Called only when it names another model than the
        running one. A model installed here before that no longer runs was
        replaced here, by a failure that unloaded it or by a person's
        ``compd model load``: it is not taken again (``--pending`` sends it,
        as a command, if that is wanted). Parsed in a worker thread, as a command is.
        """
        try:
            parsed = await self.parser.parse(payload)
        except CompdError as exc:
            log.error("desired model record ignored", reason=str(exc))
            return
        record = parsed.value
        sha256 = record.get("sha256")
        if not isinstance(sha256, str) or sha256 in self._refused_desired:
            return
        by = shorten(str(record.get("requested_by", "?")), 200)
        details = {"sha256": sha256, "requested_by": by, "rollout_id": record.get("rollout_id")}
        try:
            if record.get("schema") != DESIRED_SCHEMA:
                raise CompdError(f"the record's schema is not {DESIRED_SCHEMA!r}")
            if parsed.unread is not None:
                raise CompdError(f"the record holds a number compd does not read: {parsed.unread}")
            raw, name = request_bytes(record)
            if hashlib.sha256(raw).hexdigest() != sha256:
                raise CompdError("the model's sha256 is not the record's: altered or truncated")
            if self.installed(sha256):
                raise CompdError(
                    "it ran here before and was replaced here (a failure unloaded it, or "
                    "compd model load put another in): not taken again by itself; "
                    "compd model rollout --pending sends it"
                )
            log.info("desired model taken", name=name, **details)
            await self.load(load_request(raw, name))
        except CompdError as exc:
            self._refused_desired.add(sha256)
            log.error("desired model refused", reason=str(exc), **details)
            self.events(
                Event("model_refused", "desired model refused", details | {"reason": str(exc)})
            )
        except Exception as exc:  # a bug must not end the daemon: the running model stays
            self._refused_desired.add(sha256)
            log.exception("desired model failed to load", **details)
            reason = f"the daemon failed to check it ({type(exc).__name__})"
            self.events(
                Event("model_refused", "desired model refused", details | {"reason": reason})
            )

    def _refuse(self, answer: dict[str, Any], reason: str, by: str) -> None:
        answer |= {"result": "refused", "reason": reason}
        details = {"reason": reason, "sha256": answer["sha256"], "requested_by": by}
        log.error("remote model load refused", **details)  # the journal hears it too
        self.events(Event("model_refused", "remote model load refused", details))

    async def _admit(self, request: dict[str, Any]) -> None:
        """Raise CompdError for a replayed or stale request; else remember its id (saved)."""
        request_id = request["request_id"]
        if self.seen.seen(request_id):
            raise CompdError(
                f"request_id {request_id} was taken before: a replay, not loaded again"
            )
        sent = request.get("sent_unix_s")
        now = self.now()
        window_s = self.seen.window_s
        if isinstance(sent, bool) or not isinstance(sent, int | float) or not math.isfinite(sent):
            raise CompdError(
                "the request carries no sent_unix_s (the time it was sent): send it with "
                "compd model rollout of this version"
            )
        age_s = now - sent
        if abs(age_s) > window_s:
            when = f"{age_s:.0f} s ago" if age_s > 0 else f"dated {-age_s:.0f} s ahead"
            raise CompdError(
                f"the request was sent {when} by this machine's clock (taken within {window_s:g} s "
                "either way): stale or replayed, or a clock is wrong (NTP)"
            )
        self.seen.add(request_id, float(sent), now)
        async with self._saving:  # one write at a time, the newest ids; fsync off the event loop
            await asyncio.to_thread(self.seen.save, self.seen.content())

    async def _load(self, request: dict[str, Any], by: str) -> dict[str, Any]:
        if request.get("schema") != SCHEMA:
            raise CompdError(f"the request's schema is {request.get('schema')!r}, not {SCHEMA!r}")
        raw, name = request_bytes(request)
        sha256 = hashlib.sha256(raw).hexdigest()
        if sha256 != request.get("sha256"):
            raise CompdError(
                f"the model's sha256 is {sha256}, the request says {request.get('sha256')}: "
                "altered or truncated on the way; it was not loaded"
            )
        log.info("remote model load", name=name, sha256=sha256, requested_by=by)
        reply = await self.load(load_request(raw, name))
        for state in ("already_running", "already_loading"):
            if reply.get(state):
                return {"result": state, "model": reply["model"]}
        return {"result": "accepted", "model": reply["model"], "blend_s": reply["blend_s"]}


def checked_request(parsed: Parsed) -> dict[str, Any]:
    """The parsed request with a usable ``request_id``; raises CompdError saying what is wrong."""
    request = parsed.value
    request_id = request.get("request_id")
    if not isinstance(request_id, str) or not REQUEST_ID.match(request_id):
        raise CompdError("the request's request_id is not 1-100 letters, digits, _ . : -")
    return request
