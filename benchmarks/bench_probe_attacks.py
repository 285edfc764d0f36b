"""Probes tried as an attacker or a shop's worst day would (issue 41 item 6): what the daemon learns.

Each run: the bundled simulated machine and model (``bundled:simulated.yaml``),
a production shift of 3 h (seed 1, 10 s ticks, compd on virtual time in this
process), probes of axis Z offered at 2 h the way each path offers them:

- ``twice``: ``compd model probe Z 50`` sent twice, 10 s apart (a retry; the
  touch defaults to the time each one arrives);
- ``replay``: an MQTT ``cmd/probe`` of 50 um published twice with the same
  ``request_id`` (answered through :class:`~compd.service.fleet.remoteprobe.RemoteProbes`);
- ``flood``: 300 probes of +30 um over 46 s on the control socket;
- ``state``: a probe state file with finite absurd values (bias 1e6 um, a
  gain of 1e20, ``last_time_s`` 9e9), written before the start;
- ``huge``: ``compd model probe Z 1e308`` twice, 20 min apart.

Printed per case: the largest |learned adjustment| (um) over the shift, the
adjustment at its end, the probes by result, and whether learning was still
on at the end. The one honest probe's adjustment (a probe of the true residue
at 2 h) is printed first, for scale.

Run: ``python benchmarks/bench_probe_attacks.py [--cases twice,flood]`` (a few seconds a case).

Measured (largest |learned adjustment| over the shift, um; before issue 41 item 6 -> after):

========  ===============================  ==========================================
case      before                           after
========  ===============================  ==========================================
honest    0.01 (accepted)                  0.01 (accepted)
twice     49.60 (flagged, confirmed x2)    0.00 (flagged, too_soon)
replay    49.60 (flagged, confirmed x2)    0.00 (flagged; the replay answered, duplicate)
flood     54.90 (300 accepted)             1.03 (1 accepted, 294 answered, 5 refused)
state     7.3e21 (restored as it was)      0.00 (set aside, the prior used)
huge      0.00, learning off (Overflow)    0.00, refused at once twice, learning on
========  ===============================  ==========================================
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from compd.cli.serving import configure_logging  # noqa: E402
from compd.errors import CompdError  # noqa: E402
from compd.files.probestate import learned_path  # noqa: E402
from compd.files.yamlplace import resolve_path  # noqa: E402
from compd.service.config.loading import load_config  # noqa: E402
from compd.service.daemon import Service  # noqa: E402
from compd.service.fleet.remoteprobe import RemoteProbes  # noqa: E402
from compd.service.loop.compensator import TickRecord  # noqa: E402
from compd.service.loop.probemessages import probe_request  # noqa: E402
from compd.sim.plc.machine import SimulatedMachine  # noqa: E402
from compd.sim.plc.run import run_simulation  # noqa: E402
from tests.ports import free_port  # noqa: E402

PERIOD_S = 10.0
HOURS = 3.0
AT_TICK = round(2 * 3600 / PERIOD_S)
OUTPUT = "disp_z_um"
#: Per case, per tick after AT_TICK (0: the tick itself), the socket or MQTT messages offered.
Plan = dict[int, list[dict[str, Any]]]


def _flood() -> Plan:
    plan: Plan = {}
    for i in range(300):  # 300 in 46 s: about 65 a tick
        plan.setdefault(round(i * 46 / 300 / PERIOD_S), []).append({"measured_um": 30.0})
    return plan


CASES: dict[str, Plan] = {
    "honest": {0: [{"truth": True}]},
    "twice": {0: [{"measured_um": 50.0}], 1: [{"measured_um": 50.0}]},
    "replay": {
        0: [{"measured_um": 50.0, "request_id": "cmm-7"}],
        1: [{"measured_um": 50.0, "request_id": "cmm-7"}],
    },
    "flood": _flood(),
    "state": {},
    "huge": {0: [{"measured_um": 1e308}], 120: [{"measured_um": 1e308}]},
}


def config_doc(directory: Path) -> dict[str, Any]:
    doc: dict[str, Any] = yaml.safe_load(
        resolve_path("bundled:simulated.yaml", Path(".")).read_text()
    )
    doc["model"] = str(resolve_path("bundled:simulated_model.yaml", Path(".")))
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(directory / "state"), "save_every_ticks": 60}
    doc["recorder"] = {"enabled": False}
    doc["control_socket"] = str(directory / "c.sock")
    doc["period_s"] = PERIOD_S
    doc["probes"] = {"axes": {"Z": None}}
    doc["simulation"] = {
        "scenario": "production",
        "hours": HOURS,
        "seed": 1,
        "sample_time_s": PERIOD_S,
        "stop_at_end": True,
    }
    return doc


def run(
    directory: Path, plan: Plan, prepare: Callable[[Path], None] | None = None
) -> dict[str, Any]:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(config_doc(directory), sort_keys=False))
    config = load_config(path)
    if prepare is not None:
        prepare(config.state_dir)
    adjustments: list[float] = []
    answers: list[str] = []
    pending: list[asyncio.Task[None]] = []
    remotes: list[RemoteProbes] = []  # one, as the daemon has

    def on_tick(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        probing = service.probing
        assert probing is not None
        adjustments.append(record.probe_adjustments_um.get(OUTPUT, 0.0))
        k = len(adjustments) - AT_TICK
        for message in plan.get(k, ()):
            message = dict(message)
            if message.pop("truth", False):
                message["measured_um"] = machine.truth_now()["Z"][2]
            request_id = message.pop("request_id", None)
            if request_id is None:
                try:
                    offer(service, message | {"axis": "Z", "source": "cli"})
                except CompdError as exc:
                    answers.append(f"refused at once: {exc}")
                continue

            if not remotes:

                async def take(m: dict[str, Any], s: Service = service) -> dict[str, Any]:
                    offer(s, m)
                    return {}

                remotes.append(
                    RemoteProbes(take, lambda i, a: answers.append(f"{i}: {a}"), lambda e: None)
                )
            remote = remotes[0]
            payload = json.dumps(message | {"request_id": request_id, "axis": "Z"}).encode()
            pending.append(asyncio.get_running_loop().create_task(remote.handle(payload)))

    result = asyncio.run(run_simulation(config, on_tick=on_tick))
    status = result.status["probes"]
    z = status["axes"]["Z"]
    return {
        "max_abs_um": max(abs(a) for a in adjustments),
        "end_um": adjustments[-1],
        "results": z["results"],
        "off": status["off"],
        "answers": answers,
    }


def offer(service: Service, message: dict[str, Any]) -> None:
    probing = service.probing
    assert probing is not None
    request = probe_request(message, service.clock_wall(), probing.setup.measures, "cli")
    probing.offer(request)


def absurd_state(root: Path) -> Callable[[Path], None]:
    """A state file for the bundled model, taught by one honest probe, its numbers then made absurd."""
    run(root / "teach", CASES["honest"])
    taught = next((root / "teach" / "state" / "probes").glob("*.json"))

    def prepare(state_dir: Path) -> None:
        data = json.loads(taught.read_text())
        state = data["outputs"][OUTPUT]
        state["theta"][-1] = 1e6
        state["theta"][0] = 1e20
        state["last_time_s"] = 9e9
        target = learned_path(state_dir, data["model_sha256"])
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(json.dumps(data))

    return prepare


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES))
    args = parser.parse_args()
    configure_logging(json_lines=False, level="ERROR")  # the figures on stdout, faults on stderr
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        print(f"{'case':8} {'max |adj| um':>12} {'end um':>9}  learning  results")
        for name in args.cases.split(","):
            prepare = absurd_state(root) if name == "state" else None
            out = run(root / name, CASES[name], prepare)
            on = "off" if out["off"] else "on"
            print(
                f"{name:8} {out['max_abs_um']:12.2f} {out['end_um']:9.2f}  {on:8}  {out['results']}"
            )
            for answer in sorted(set(out["answers"])):
                print(f"{'':10}answer: {answer[:160]}")


if __name__ == "__main__":
    main()
