"""cmd/probe requests (compd.service.fleet.remoteprobe): each request id taken once, across restarts too."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

from compd.faultlog import Event
from compd.service.fleet.remoteprobe import FILE, KEEP_S, RemoteProbes
from compd.service.fleet.seenrequests import SeenRequests


class Station:
    """What the daemon does with a probe (counted), and the replies it sends, in order."""

    def __init__(self) -> None:
        self.taken: list[dict[str, Any]] = []
        self.replies: list[tuple[str, dict[str, Any]]] = []
        self.events: list[Event] = []

    async def take(self, message: dict[str, Any]) -> dict[str, Any]:
        self.taken.append(message)
        await asyncio.sleep(0)
        return {"taken": True, "last": {"result": "accepted", "innovation_um": 0.4}}

    def probes(self, path: Path | None = None) -> RemoteProbes:
        seen = SeenRequests(path, window_s=KEEP_S)
        return RemoteProbes(
            self.take, lambda i, a: self.replies.append((i, a)), self.events.append, seen=seen
        )


def payload(request_id: str = "cmm-7", **more: Any) -> bytes:
    return json.dumps({"request_id": request_id, "axis": "Z", "measured_um": 50.0} | more).encode()


def test_a_replayed_request_is_answered_with_the_first_answer_and_not_taken_again() -> None:
    """The same request_id twice (a retry, a broker's redelivery, an attacker's copy): one probe."""
    station = Station()
    probes = station.probes()

    async def main() -> None:
        await probes.handle(payload())
        await probes.handle(payload())

    asyncio.run(main())
    assert len(station.taken) == 1
    (_, first), (_, again) = station.replies
    assert first["ok"] is True and "duplicate" not in first
    assert again == first | {"duplicate": True}


def test_a_replay_arriving_while_the_first_is_taken_waits_for_its_answer() -> None:
    """Two copies at once: the second is not taken, and answered once the first is."""
    station = Station()
    probes = station.probes()

    async def main() -> None:
        await asyncio.gather(probes.handle(payload()), probes.handle(payload()))

    asyncio.run(main())
    assert len(station.taken) == 1
    assert sorted(a.get("duplicate", False) for _, a in station.replies) == [False, True]


def test_a_replay_after_a_restart_is_refused_by_its_id(tmp_path: Path) -> None:
    """The ids are kept in the state directory: a new daemon refuses a request the last one took."""
    first = Station()
    asyncio.run(first.probes(tmp_path / FILE).handle(payload()))
    second = Station()
    asyncio.run(second.probes(tmp_path / FILE).handle(payload()))
    assert second.taken == []
    ((_, answer),) = second.replies
    assert answer["ok"] is False and answer["duplicate"] is True
    assert "already taken (before the daemon restarted)" in answer["error"]


def test_a_shift_is_accepted_at_the_machine_never_over_the_broker() -> None:
    """accept_shift over MQTT: refused with the command a person runs at the machine."""
    station = Station()
    asyncio.run(station.probes().handle(payload(accept_shift=True)))
    assert station.taken == []
    ((_, answer),) = station.replies
    assert answer["ok"] is False and "compd model probe --accept-shift" in answer["error"]
