"""What the probes taught, kept in the state directory: the learners' states per model, and the probe log.

Under ``<state dir>/probes/``:

- ``<model sha256>.json``: per output, :meth:`OutputLearner.state` of the
  model with that sha256, replaced atomically (temp file, fsync, rename) at
  each save. A machine keeps its updates only for the same model: a newly
  loaded model starts from its own prior, and a roll-out of the same file
  (same sha) finds them again.
- ``log.jsonl``: one JSON line per probe as the update took it (or refused
  it) and per reset, appended and fsynced, never rewritten: what ``compd
  model updates`` lists.

Reading checks every number (finite, JSON's ``NaN`` refused), the sha256
the file names, each learner's shapes and bounds (:meth:`OutputLearner.restore`:
gains on their rails, the bias within the learned adjustment's bound, a
positive-definite covariance, no time in the future).
A learned-state file that fails is set aside (renamed
``<name>.corrupt-<UTC time>``, nothing deleted) and the outputs start from
their prior; the caller is told why, to log it once. A log line that fails
is skipped and named; the lines after it are read.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from compd.errors import ModelError
from compd.files.unreadable import finite, json_int, set_aside, write_atomic
from compd.model.probelearner import RESTORE_SKEW_S, OutputLearner
from compd.model.proberegressors import RegressorWindow
from compd.model.probesettings import ProbeSettings
from compd.model.probeupdate import ProbeStep
from compd.model.updateprior import Prior

#: The folder of the probe files in the state directory.
PROBES_DIR = "probes"
#: The probe log's name in it.
LOG_NAME = "log.jsonl"
#: The learned-state file's format tag.
STATE_FORMAT = "compd.probe-state/1"
#: What a log line's ``result`` may be: the update's results, a probe refused before the
#: update (its touch older than the regressors kept), a reset to the prior.
RESULTS = ("accepted", "flagged", "confirmed", "rejected", "refused", "reset")


def probes_dir(state_dir: Path) -> Path:
    return Path(state_dir) / PROBES_DIR


def learned_path(state_dir: Path, sha256: str) -> Path:
    """The learned-state file of the model with ``sha256``."""
    if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
        raise ValueError(f"a model's sha256 is 64 lower-case hex digits, not {sha256!r}")
    return probes_dir(state_dir) / f"{sha256}.json"


@dataclass(frozen=True)
class ProbeRecord:
    """One line of the probe log; um in the model's sense (:func:`probed_thermal_error_um`).

    ``touched_s``: when the probe touched (unix s); ``source``: where the
    value came from (``plc``, ``socket``, ``cli``, ``mqtt``); ``measured_um``:
    the thermal error it gave; ``predicted_before_um`` / ``_after_um``: the
    model's output at the touch before and after the update;
    ``residue_um`` and ``offset_um``: what the probe read and the offset in
    force, when it read a residue; ``reason``: why it was refused, or who
    reset.
    """

    touched_s: float
    model_sha256: str
    output: str
    source: str
    result: str
    axis: str | None = None
    measured_um: float | None = None
    predicted_before_um: float | None = None
    predicted_after_um: float | None = None
    predicted_sd_um: float | None = None
    innovation_before_um: float | None = None
    innovation_after_um: float | None = None
    bounded: bool = False
    residue_um: float | None = None
    offset_um: float | None = None
    logged_s: float | None = None
    reason: str | None = None

    @classmethod
    def of_step(
        cls, step: ProbeStep, *, model_sha256: str, output: str, source: str, **more: Any
    ) -> ProbeRecord:
        """The log line of one step the learner returned (``more``: axis, residue_um, ...)."""
        sd = step.predicted_sd_um
        return cls(
            touched_s=step.time_s,
            model_sha256=model_sha256,
            output=output,
            source=source,
            result=step.result,
            measured_um=step.measured_um,
            predicted_before_um=step.predicted_um,
            predicted_after_um=step.measured_um - step.innovation_after_um,
            predicted_sd_um=sd if math.isfinite(sd) else None,
            innovation_before_um=step.innovation_before_um,
            innovation_after_um=step.innovation_after_um,
            bounded=step.bounded,
            **more,
        )

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}

    @classmethod
    def from_dict(cls, data: object) -> ProbeRecord:
        """A record from a log line's mapping; ValueError naming the key that is wrong."""
        if not isinstance(data, Mapping):
            raise ValueError("the line is not a JSON object")
        fields = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - set(fields))
        if unknown:
            raise ValueError(f"unknown keys {unknown}")
        values: dict[str, Any] = {}
        for name, value in data.items():
            kind = str(fields[name].type)
            if "float" in kind:
                values[name] = finite(value, name)
            elif kind == "bool":
                if not isinstance(value, bool):
                    raise ValueError(f"{name} is {value!r}, not true or false")
                values[name] = value
            elif not isinstance(value, str):
                raise ValueError(f"{name} is {value!r}, not a string")
            else:
                values[name] = value
        missing = [
            n for n, f in fields.items() if f.default is dataclasses.MISSING and n not in data
        ]
        if missing:
            raise ValueError(f"missing keys {missing}")
        if values["result"] not in RESULTS:
            raise ValueError(f"result is {values['result']!r}, not one of {', '.join(RESULTS)}")
        return cls(**values)


def append_record(state_dir: Path, record: ProbeRecord) -> None:
    """Append ``record`` to the probe log and fsync it (a probe is rare; losing one is not)."""
    path = probes_dir(state_dir) / LOG_NAME
    path.parent.mkdir(parents=True, exist_ok=True)
    line = json.dumps(record.to_dict(), allow_nan=False, sort_keys=True) + "\n"
    with path.open("a", encoding="utf-8") as f:
        f.write(line)
        f.flush()
        os.fsync(f.fileno())


@dataclass(frozen=True)
class ProbeLog:
    """The probe log as read: its records in file order, and the lines that could not be read."""

    path: Path
    records: tuple[ProbeRecord, ...]
    unreadable: tuple[str, ...] = ()


def read_log(state_dir: Path) -> ProbeLog:
    """Every readable line of the probe log (none when there is no log yet)."""
    path = probes_dir(state_dir) / LOG_NAME
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        return ProbeLog(path, ())
    records, unreadable = [], []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            records.append(ProbeRecord.from_dict(_loads(line)))
        except ValueError as exc:
            unreadable.append(f"{path}: line {number}: {exc}")
    return ProbeLog(path, tuple(records), tuple(unreadable))


def save_learned(
    state_dir: Path, sha256: str, learners: Mapping[str, OutputLearner], now_s: float
) -> Path:
    """Write the learners' states of the model with ``sha256`` atomically; the file written."""
    states = {name: learner.state() for name, learner in learners.items()}
    return write_learned(state_dir, sha256, states, now_s)


def write_learned(
    state_dir: Path, sha256: str, states: Mapping[str, Mapping[str, Any]], now_s: float
) -> Path:
    """:func:`save_learned` of states already taken (:meth:`OutputLearner.state`: the daemon takes
    them in the tick and writes them from a worker thread)."""
    path = learned_path(state_dir, sha256)
    data = {
        "format": STATE_FORMAT,
        "model_sha256": sha256,
        "saved_s": now_s,
        "outputs": dict(states),
    }
    write_atomic(path, json.dumps(data, allow_nan=False, indent=1).encode())
    return path


def reset_learned(state_dir: Path, sha256: str) -> bool:
    """Delete what the probes taught the model with ``sha256``: it runs on its prior. True if there was a state."""
    path = learned_path(state_dir, sha256)
    try:
        path.unlink()
    except FileNotFoundError:
        return False
    return True


@dataclass(frozen=True)
class RestoredLearners:
    """The learners to run, and what the caller should say once.

    ``restored``: the outputs that resumed what they had learned (the rest
    start from their prior); ``problem``: why the file could not be used;
    ``set_aside_as``: where it was moved (None: it was not there, or could
    not be moved).
    """

    learners: dict[str, OutputLearner]
    restored: tuple[str, ...] = ()
    problem: str | None = None
    set_aside_as: Path | None = None


def restore_learners(
    state_dir: Path,
    sha256: str,
    setups: Mapping[str, tuple[Prior, ProbeSettings]],
    window: RegressorWindow | None = None,
    *,
    set_aside_unreadable: bool = True,
    now_s: float | None = None,
    skew_s: float = RESTORE_SKEW_S,
) -> RestoredLearners:
    """One learner per output of ``setups`` (its prior and settings), resumed from the file where it has one.

    A file that cannot be used is set aside and every output starts from
    its prior (a wrong state must never stop the daemon, nor steer it);
    a reader that is not the daemon passes ``set_aside_unreadable=False``.
    Outputs the file holds but ``setups`` does not name are left out.
    ``now_s`` (unix s): no time in the file may be later than it (by more
    than ``skew_s``).
    """
    fresh = {
        name: OutputLearner(prior, settings, window) for name, (prior, settings) in setups.items()
    }
    path = learned_path(state_dir, sha256)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        return RestoredLearners(fresh)
    except OSError as exc:
        return RestoredLearners(fresh, problem=f"{path}: cannot be read ({exc})")
    try:
        learners, restored = _restored(raw, sha256, setups, window, now_s, skew_s)
    except ValueError as exc:
        problem = f"{path}: {exc}"
        if not set_aside_unreadable:
            return RestoredLearners(fresh, problem=problem)
        try:
            moved: Path | None = set_aside(path)
        except OSError as error:
            moved, problem = None, f"{problem}; it could not be set aside ({error})"
        return RestoredLearners(fresh, problem=problem, set_aside_as=moved)
    return RestoredLearners(fresh | learners, restored)


def _restored(
    raw: bytes,
    sha256: str,
    setups: Mapping[str, tuple[Prior, ProbeSettings]],
    window: RegressorWindow | None,
    now_s: float | None,
    skew_s: float,
) -> tuple[dict[str, OutputLearner], tuple[str, ...]]:
    data = _loads(raw.decode("utf-8", errors="replace"))
    if not isinstance(data, Mapping) or data.get("format") != STATE_FORMAT:
        raise ValueError(f"it is not a {STATE_FORMAT} file")
    if data.get("model_sha256") != sha256:
        raise ValueError(
            f"it holds the state of model {str(data.get('model_sha256'))[:12]}, not {sha256[:12]}"
        )
    saved_s = finite(data.get("saved_s"), "saved_s")
    if now_s is not None and saved_s > now_s + skew_s:
        raise ValueError(f"saved_s is {saved_s - now_s:.0f} s in the future")
    outputs = data.get("outputs")
    if not isinstance(outputs, Mapping):
        raise ValueError("outputs is not a mapping")
    learners = {}
    for name, state in outputs.items():
        if name not in setups:
            continue
        prior, settings = setups[name]
        try:
            learners[name] = OutputLearner.restore(
                prior, settings, state, window, now_s=now_s, skew_s=skew_s
            )
        except ModelError as exc:
            raise ValueError(f"outputs.{name}: {exc.message}") from exc
    return learners, tuple(learners)


def _loads(text: str) -> Any:
    """JSON with JSON's own numbers only: ``NaN`` and ``Infinity`` refused, huge integers infinite."""

    def refuse(constant: str) -> float:
        raise ValueError(f"{constant} is not a number a compd file holds")

    try:
        return json.loads(text, parse_int=json_int, parse_constant=refuse)
    except json.JSONDecodeError as exc:
        raise ValueError(f"not JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
