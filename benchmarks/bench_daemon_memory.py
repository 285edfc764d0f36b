"""``compd run``'s peak memory and what it maps, the way it was beside the way it is, per bundled config.

The daemon steps the difference equations its model file carries, and the
simulated driver reads a plain CSV record with numpy alone. Before, it
converted the model at load (``scipy.signal``, ``scipy.linalg``'s matrix
logarithm for the bundled 10 s model at the 1 s loop) and read every
replayed record through pandas. Each bundled daemon config runs twice:

- *before*: the model file without its ``difference_equations`` and this
  compd converting it at load as it used to, the replayed record read by
  ``load_data`` (pandas): the same code otherwise, so the difference is the
  loading alone. ``--before-python PY`` runs an older install instead
  (e.g. a venv of the main branch: ``PY -m compd.cli run``), on the same
  configs and model file without equations;
- *after*: this compd, the bundled files as shipped.

A config with a ``simulation`` section runs without it, its PLC served by
``compd simulate-machine`` in a process of its own (as an edge PC talks to
a real controller); a config for a PLC that nobody serves (``record.yaml``)
is left out. Per run: the peak resident memory (``ru_maxrss``) and whether
scipy and pandas were mapped into the process (its ``/proc/PID/maps``,
read from here each second) or imported (``sys.modules`` at exit). This process imports neither numpy nor compd (a
child's ``ru_maxrss`` counts its parent's pages up to ``exec``).

Whether compd's modules start from bytecode caches moves the figures: compiled
from source at every start (``PYTHONDONTWRITEBYTECODE=1`` and no ``__pycache__``
in a checkout) the peak is 0.3-1.3 MB higher than from the caches a wheel's
install writes; the first line says which. Address-space randomisation moves
one run's peak by up to +-0.5 MB.

Target: every *after* run < 60 MB and maps neither.
Run: ``PYTHONPATH=. python benchmarks/bench_daemon_memory.py [--duration-s 15]``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests.ports (simconfig's too)
from tests.ports import wait_listening

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "config"
#: The daemon configs measured, and the PLC port each is served on here.
CASES = {"simulated.yaml": 15940, "replay.yaml": None, "compd.example.yaml": None}
HEAVY = ("scipy", "pandas")

#: Runs ``compd ARGV``; at exit reports (on stderr, one JSON line) which of them it imported.
#: ``BEFORE=1``: this compd as it loaded models and records before (converting, pandas).
CHILD = """
import atexit, json, os, runpy, sys
def report():
    found = {'imported': sorted(h for h in ('scipy', 'pandas') if h in sys.modules)}
    print('HEAVY ' + json.dumps(found), file=sys.stderr)
atexit.register(report)
if os.environ.get('BEFORE') == '1':
    import compd.files.modelfile as modelfile, compd.files.plaincsv as plaincsv
    compile_ = modelfile.ModelFile.compile
    def converting(self, sample_time_s=None, *, convert=True):
        return compile_(self, sample_time_s, convert=True)
    modelfile.ModelFile.compile = converting
    plaincsv.read_plain_csv = lambda path: None
sys.argv = ['compd', *sys.argv[1:]]
runpy.run_module('compd.cli', run_name='__main__')
"""


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def without_equations(model: Path, destination: Path) -> Path:
    """``model`` with its ``difference_equations`` section cut (text; the rest as written)."""
    lines, skipping = [], False
    for line in model.read_text().splitlines():
        if line.startswith("difference_equations:"):
            skipping = True
            while lines and lines[-1].startswith("#"):
                lines.pop()  # the section's own comment
            continue
        if skipping and (line.startswith("#") or (line and not line.startswith(" "))):
            skipping = False
        if not skipping:
            lines.append(line)
    destination.write_text("\n".join(lines) + "\n")
    return destination


def configs(name: str, directory: Path, port: int | None, *, before: bool) -> tuple[Path, Path]:
    """The daemon's config and (for a simulated one) the machine's, in ``directory``."""
    doc: dict[str, Any] = yaml.safe_load((CONFIGS / name).read_text())
    model = doc.get("model")
    if model:
        source = CONFIGS / str(model).removeprefix("bundled:")
        doc["model"] = str(
            without_equations(source, directory / f"before-{source.name}") if before else source
        )
    doc["state"] = {"directory": str(directory / "state")}
    doc["control_socket"] = str(directory / f"{name}.sock")
    if "recorder" in doc:
        doc["recorder"]["directory"] = str(directory / "records")
    for driver in doc["drivers"].values():
        settings = driver.get("settings", {})
        if "port" in settings and port is not None:
            settings["host"], settings["port"] = "127.0.0.1", port
    machine = directory / f"machine-{name}"
    machine.write_text(yaml.safe_dump(doc))
    doc.pop("simulation", None)
    daemon = directory / f"daemon-{name}"
    daemon.write_text(yaml.safe_dump(doc))
    return daemon, machine


def run_daemon(
    python: str, config: Path, duration_s: float, *, before: bool, older: bool = False
) -> dict[str, Any]:
    """Peak RSS (MB) and the heavy libraries of one ``compd run``.

    ``before``: this compd as it loaded models before; ``older``: ``python`` is
    another install, run outside this checkout (its own compd, not this one's).
    """
    env = {**os.environ, "BEFORE": "1" if before else "0"}
    if older:
        env.pop("PYTHONPATH", None)
    argv = [python, "-c", CHILD, "run", "--config", str(config), "--duration-s", str(duration_s)]
    log = config.with_suffix(".stderr")
    with log.open("w") as stderr:
        child = subprocess.Popen(
            [*argv, "--log-format", "json"], cwd=config.parent if older else None,
            stdout=subprocess.DEVNULL, stderr=stderr, env=env,
        )  # fmt: skip
    mapped: set[str] = set()
    while True:  # what is mapped, read from outside (the child reads nothing); wait4 reaps it
        pid, status, usage = os.wait4(child.pid, os.WNOHANG)
        if pid:
            break
        with contextlib.suppress(OSError):
            maps = Path(f"/proc/{child.pid}/maps").read_text()
            mapped |= {h for h in HEAVY if f"/{h}/" in maps or f"/{h}.libs/" in maps}
        time.sleep(1.0)
    child.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
    err = log.read_text()
    reports = [line for line in err.splitlines() if line.startswith("HEAVY ")]
    if os.waitstatus_to_exitcode(status) not in (0, 3) or not reports:
        raise SystemExit(f"compd run --config {config} failed:\n{err[-3000:]}")
    return {
        "rss_mb": usage.ru_maxrss / 1024,
        "mapped": sorted(mapped),
        **json.loads(reports[-1][6:]),
    }


def bytecode_caches() -> str:
    """Whether compd's modules start from ``__pycache__`` here, or are compiled at every start."""
    module = ROOT / "compd" / "cli" / "daemon.py"
    cached = Path(importlib.util.cache_from_source(str(module)))
    if cached.is_file() and cached.stat().st_mtime >= module.stat().st_mtime:
        return "present (as a wheel's install writes them)"
    if os.environ.get("PYTHONDONTWRITEBYTECODE"):
        return "none, PYTHONDONTWRITEBYTECODE set: compiled from source at every start"
    return "none yet: the first run writes them"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=15.0)
    parser.add_argument("--before-python", help="an older install's python, for 'before'")
    args = parser.parse_args()
    passed = True
    print(f"compd run for {args.duration_s:g} s per config: peak RSS and scipy/pandas mapped")
    print(f"compd's bytecode caches: {bytecode_caches()}\n")
    print(f"{'config':22} {'before MB':>10} {'before maps':>16} {'after MB':>9} {'after maps':>11}")
    with tempfile.TemporaryDirectory(dir="/tmp") as tmp:
        for name, port in CASES.items():
            rows = {}
            for before in (True, False):
                directory = Path(tmp) / ("before" if before else "after")
                directory.mkdir(exist_ok=True)
                plc = free_port() if port is not None else None
                daemon, machine_config = configs(name, directory, plc, before=before)
                machine = None
                if plc is not None:
                    machine = subprocess.Popen(
                        [sys.executable, "-m", "compd.cli", "simulate-machine", "--config",
                         str(machine_config)],
                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                    )  # fmt: skip
                    wait_listening(plc, machine)
                older = before and args.before_python is not None
                python = args.before_python if older else sys.executable
                try:
                    rows[before] = run_daemon(
                        python, daemon, args.duration_s, before=before and not older, older=older
                    )
                finally:
                    if machine is not None:
                        machine.terminate()
                        machine.wait()
            old, new = rows[True], rows[False]
            ok = new["rss_mb"] < 60 and not new["mapped"] and not new["imported"]
            passed &= ok
            print(
                f"{name:22} {old['rss_mb']:10.1f} {','.join(old['mapped']) or '-':>16} "
                f"{new['rss_mb']:9.1f} {','.join(new['mapped']) or '-':>11}  "
                f"< 60 MB, neither: {'PASS' if ok else 'FAIL'}"
            )
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
