"""Who publishes as a machine_id (mqttclaim), and a register's value scaled without rounding noise (points)."""

from __future__ import annotations

import subprocess
import sys

from compd.service.fleet.claim import Claim, Instance
from compd.service.loop.points import SignalPoint


def _birth(instance: Instance, session: int) -> dict[str, object]:
    return {"kind": "birth", "session": session, "instance": instance.describe()}


def test_a_crashed_predecessor_on_this_host_is_no_rival_but_a_live_daemon_elsewhere_is():
    """A birth from this host whose pid is gone is stale; one from another host with no death keeps the id."""
    me = Instance.this_process()
    gone = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True
    )
    crashed = Instance("crashed", me.host, int(gone.stdout), me.started_unix_s - 60)
    elsewhere = Instance("elsewhere", "mill-b-pc", 4321, me.started_unix_s - 30)
    claim = Claim(me)
    assert claim.heard("birth", _birth(crashed, 1))
    assert claim.rival(publishing=False) is None
    assert claim.heard("birth", _birth(elsewhere, 2))
    assert claim.rival(publishing=False) == _birth(elsewhere, 2)
    claim.heard("death", {"kind": "death", "session": 2, "instance": elsewhere.describe()})
    assert claim.rival(publishing=False) is None, "its death ends its claim"
    assert not claim.heard("birth", _birth(me, 3)), "its own birth is nobody's rival"


def test_while_publishing_only_a_daemon_started_earlier_is_a_rival():
    """Of two daemons publishing at once, the later one yields: the earlier keeps the machine_id."""
    me = Instance.this_process()
    later = Instance("later", "other-pc", 1, me.started_unix_s + 10)
    earlier = Instance("earlier", "other-pc", 2, me.started_unix_s - 10)
    claim = Claim(me)
    claim.heard("birth", _birth(later, 5))
    assert claim.rival(publishing=True) is None
    assert claim.rival(publishing=False) is not None, "before publishing, any live one"
    claim.heard("birth", _birth(earlier, 6))
    assert claim.rival(publishing=True) == _birth(earlier, 6)


def test_a_register_scaled_by_a_hundredth_reads_as_its_decimal():
    """2115 at scale 0.01 is 21.15 (not 21.150000000000002); 0 at scale -1 is 0.0, never -0.0."""
    assert repr(SignalPoint("T", "plc", "input:0", 0.01, kind="int").convert(2115.0)) == "21.15"
    assert repr(SignalPoint("T", "plc", "input:0", 0.1).convert(3.0)) == "0.3"
    assert repr(SignalPoint("T", "plc", "input:0", -1.0).convert(0.0)) == "0.0"
    assert SignalPoint("P", "plc", "input:1", 0.37).convert(100.0) == 100.0 * 0.37
