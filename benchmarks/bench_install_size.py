"""The daemon-only install beside the full one: the venv on disk and ``compd run``'s peak memory.

Fresh venvs in a temporary directory, each ``python -m venv`` then ``pip
install -c .ci/requirements.lock`` (no editable install; the checkout's
tracked files copied first, so no build/ lands in the checkout):

- daemon only: ``.`` (``pip install compd``: the daemon, its drivers, the
  operations commands), what an edge PC gets;
- with OPC UA: ``'.[opcua]'`` (asyncua and cryptography), an edge PC whose
  controller speaks OPC UA;
- with the toolkit: ``'.[toolkit]'`` (scipy, pandas, plotly, scikit-learn,
  EMD-signal, and OPC UA), which is what every install was before the split
  (issue 43: 571 MB);
- with ``--before REF``: ``.`` at that git revision (e.g. the commit before
  the split), the literal before.

For each: the venv's disk use as ``du -sh`` counts it (pip, setuptools and
the byte-compiled files included), and the largest distributions (the files
their RECORD lists). Then ``compd run`` for ``--run-s`` seconds on a config for
a real machine (Modbus TCP; the twin serves it from the full venv's own
process, as a PLC would), its peak resident memory (``ru_maxrss``), in each
venv: with the bundled model as it is and with its TFs at the loop's period
(numpy alone steps those); beside it, the README's first command (the twin
inside ``compd run``'s process) in the full venv, and the daemon-only venv's
answer to it and to ``compd fit`` (exit status 2 and one line naming
``compd[toolkit]``).

This process imports neither numpy nor compd (a child's ``ru_maxrss`` counts
its parent's pages up to ``exec``). Three or four installs: several minutes; a
benchmark, not a test. Target: the daemon-only venv <= 571 / 3 = 190 MB.
Run: ``python benchmarks/bench_install_size.py [--before REF] [--run-s 20]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests.ports (simconfig's too)
from simconfig import simulated_and_real

from tests.ports import wait_listening

ROOT = Path(__file__).resolve().parents[1]
#: The issue's figure: a fresh venv after ``pip install -c .ci/requirements.lock .``, before the split.
BEFORE_MB = 571
TARGET_MB = BEFORE_MB / 3

#: A model file's discrete TFs resampled to a period (argv: source, destination, period_s),
#: run by the full venv's python: the daemon steps these with numpy alone.
AT_LOOP_RATE = """
import sys, yaml
from compd.model.transfer import DiscreteTF, resample_discrete
source, destination, period_s = sys.argv[1], sys.argv[2], float(sys.argv[3])
doc = yaml.safe_load(open(source))
for output in doc["outputs"].values():
    for sub in output["submodels"]:
        tf = sub["tf"]
        d = DiscreteTF.from_coefficients(tf["num"], tf["den"], tf.get("nk", 0))
        r = resample_discrete(d, float(doc["sample_time_s"]), period_s)
        tf.update(num=[float(v) for v in r.num], den=[float(v) for v in r.den], nk=int(r.nk))
doc["sample_time_s"] = period_s
open(destination, "w").write(yaml.safe_dump(doc, sort_keys=False))
"""


@dataclass
class Venv:
    label: str
    path: Path

    @property
    def python(self) -> Path:
        return self.path / "bin" / "python"

    @property
    def compd(self) -> list[str]:
        return [str(self.path / "bin" / "compd")]


def copy_tree(destination: Path, ref: str | None) -> Path:
    """The checkout's files (tracked and new, as they are now), or revision ``ref``'s, in ``destination``."""
    destination.mkdir(parents=True)
    if ref is not None:
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", ref], check=True, capture_output=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(destination)], input=archive, check=True)
        return destination
    listed = subprocess.run(
        ["git", "-C", str(ROOT), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        check=True, capture_output=True, text=True,
    ).stdout.split("\0")  # fmt: skip
    for name in filter(None, listed):
        source = ROOT / name
        if source.is_file():  # a tracked file deleted in the checkout is not copied
            (destination / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, destination / name)
    return destination


def install(label: str, venv: Path, source: Path, extras: str) -> Venv:
    """A fresh venv with ``source`` (+ ``extras``) installed against ``source``'s own lock."""
    start = time.monotonic()
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    target = f"{source}{extras}"
    lock = source / ".ci" / "requirements.lock"
    done = subprocess.run(
        [str(venv / "bin" / "pip"), "install", "-q", "-c", str(lock), target],
        capture_output=True, text=True,
    )  # fmt: skip
    if done.returncode != 0:
        raise SystemExit(f"pip install {target} failed:\n{done.stdout}{done.stderr}")
    print(f"  {label}: installed in {time.monotonic() - start:.0f} s", flush=True)
    return Venv(label, venv)


def disk_mb(path: Path) -> float:
    """Disk use in MB (MiB) as ``du -sh`` reports it: allocated blocks, hard links once."""
    kib = subprocess.run(["du", "-sk", str(path)], check=True, capture_output=True, text=True)
    return int(kib.stdout.split()[0]) / 1024


def distributions_mb(venv: Venv) -> dict[str, float]:
    """Each installed distribution's files (its RECORD), MB, apparent size."""
    sizes: dict[str, float] = {}
    for record in venv.path.glob("lib/python*/site-packages/*.dist-info/RECORD"):
        site = record.parent.parent
        total = 0
        for line in record.read_text().splitlines():
            file = site / line.split(",")[0]
            if file.is_file():
                total += file.stat().st_size
        name = record.parent.name.removesuffix(".dist-info").rsplit("-", 1)[0]
        sizes[name] = total / 2**20
    return sizes


def peak_rss_mb(argv: list[str], *, cwd: Path) -> tuple[int, float, str]:
    """Exit status, peak resident MB of one process, and its stderr's last line."""
    with tempfile.TemporaryFile() as err:
        child = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, cwd=cwd)
        _, status, usage = os.wait4(child.pid, 0)
        err.seek(0)
        lines = err.read().decode(errors="replace").strip().splitlines()
    return os.waitstatus_to_exitcode(status), usage.ru_maxrss / 1024, lines[-1] if lines else ""


def configs(directory: Path, full: Venv, source: Path) -> tuple[Path, Path, Path]:
    """The bundled simulated config on a free port, and the same without its ``simulation``:
    with the bundled model as it is, and with its TFs at the loop's period."""
    simulated, real = simulated_and_real(directory, source)
    doc = yaml.safe_load(real.read_text())
    model_at_period = directory / "model_at_period.yaml"
    subprocess.run(
        [str(full.python), "-c", AT_LOOP_RATE, doc["model"], str(model_at_period),
         str(doc["period_s"])],
        check=True,
    )  # fmt: skip
    doc["model"] = str(model_at_period)
    doc["control_socket"] = str(directory / "numpy.sock")
    at_period = directory / "real_at_period.yaml"
    at_period.write_text(yaml.safe_dump(doc))
    return simulated, real, at_period


def shown(status: int, rss: float, last: str) -> str:
    if status == 0:
        return f"{rss:7.1f} MB"
    return f"exit {status}: {last.removeprefix('compd: error: ')[:90]}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", metavar="REF", help="also install this git revision's '.'")
    parser.add_argument("--run-s", type=float, default=20.0, help="compd run's duration (20)")
    parser.add_argument("--keep", type=Path, help="build the venvs here and keep them")
    args = parser.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="compd-install-", dir="/tmp"))
    try:
        return measure(work, args.before, args.run_s)
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)


def measure(work: Path, before: str | None, run_s: float) -> int:
    print(f"python {sys.version.split()[0]}; venvs in {work}", flush=True)
    source = copy_tree(work / "src", None)
    venvs = [
        install("daemon only (pip install compd)", work / "daemon", source, ""),
        install("with the toolkit (compd[toolkit])", work / "full", source, "[toolkit]"),
        install("with OPC UA (compd[opcua])", work / "opcua", source, "[opcua]"),
    ]
    if before is not None:
        old = copy_tree(work / "before-src", before)
        venvs.append(install(f"before ({before}: pip install compd)", work / "before", old, ""))
    daemon, full = venvs[0], venvs[1]

    print(f"\n{'venv':44} {'du -sh':>8}  target")
    sizes = {v.label: disk_mb(v.path) for v in venvs}
    passed = sizes[daemon.label] <= TARGET_MB
    for label, mb in sizes.items():
        target = (
            f"<= {TARGET_MB:.0f} MB {'PASS' if passed else 'FAIL'}" if label == daemon.label else ""
        )
        print(f"{label:44} {mb:6.0f} MB  {target}")
    print(f"{'issue 43, before the split':44} {BEFORE_MB:6.0f} MB")

    base, whole = distributions_mb(daemon), distributions_mb(full)
    print("\nlargest distributions of the daemon-only venv (MB, their files):")
    for name, mb in sorted(base.items(), key=lambda kv: -kv[1])[:10]:
        print(f"  {name:32} {mb:6.1f}")
    added = {name: mb for name, mb in whole.items() if name not in base}
    print(f"what the toolkit adds: {sum(added.values()):.0f} MB")
    for name, mb in sorted(added.items(), key=lambda kv: -kv[1]):
        print(f"  {name:32} {mb:6.1f}")

    directory = work / "run"
    directory.mkdir()
    simulated, real, at_period = configs(directory, full, source)
    port = yaml.safe_load(real.read_text())["drivers"]["plc"]["settings"]["port"]
    run = ["run", "--duration-s", f"{run_s:g}", "--log-format", "json", "--config"]
    print(f"\ncompd run for {run_s:g} s, a real machine's config: peak resident memory")
    machine = subprocess.Popen(
        [*full.compd, "simulate-machine", "--config", str(simulated)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        wait_listening(port, machine)
        print(f"{'venv':44} {'model at the loop period':>26}  {'bundled model as it is'}")
        for venv in venvs:
            numpy_run = peak_rss_mb([*venv.compd, *run, str(at_period)], cwd=directory)
            as_is = peak_rss_mb([*venv.compd, *run, str(real)], cwd=directory)
            print(f"{venv.label:44} {shown(*numpy_run):>26}  {shown(*as_is)}")
            if venv is daemon:
                passed &= numpy_run[0] == 0
    finally:
        machine.terminate()
        machine.wait()

    print("\nthe README's first command (the twin in compd run's process)")
    sim_argv = [
        "run",
        "--config",
        str(simulated),
        "--duration-s",
        f"{run_s:g}",
        "--log-format",
        "json",
    ]
    print(f"  {full.label:42} {shown(*peak_rss_mb([*full.compd, *sim_argv], cwd=directory))}")
    print(f"  {daemon.label:42} {shown(*peak_rss_mb([*daemon.compd, *sim_argv], cwd=directory))}")
    fit = peak_rss_mb([*daemon.compd, "fit", "--data", "x.csv", "--out", "m.yaml"], cwd=directory)
    print(f"  {'compd fit, daemon only':42} {shown(*fit)}")
    passed &= fit[0] == 2 and "compd[toolkit]" in fit[2]
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
