"""Persistence of the running model's state, and the installed model, in the state directory.

The daemon saves its model state (TF delay lines and input references, see
:class:`~compd.model.compiled.ModelState`), the offsets it last wrote and the
model's sha256 every N ticks and at shutdown. Every file is written
atomically: a temporary file in the same directory, ``fsync``, ``rename``
over the old one, ``fsync`` of the directory. A crash leaves the old file or
the new one, never half of either.

Resume policy (:func:`resume_decision`): a saved state is used only if it
belongs to the same model (same sha256) and is younger than
``resume_max_age_s``. Otherwise the model starts at steady state with the
first good inputs, so a cold machine starts with zero offsets rather than a
transient, and a warm one with its equilibrium offsets.

A state file that cannot be read (not JSON, another format, a number that is
not finite or out of range: ``"ticks": Infinity``, ``saved_at_unix_s: NaN``,
an integer of 5,000 digits) is set aside (:func:`~compd.service.store.unreadable.set_aside`: renamed to
``state.json.corrupt-<UTC time>``, nothing deleted) with one ERROR line, and
the daemon starts as without one: a corrupt file must never stop it starting.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import structlog

from compd.errors import CompdError, ModelError
from compd.files.unreadable import write_atomic
from compd.files.yamlplace import shorten
from compd.model.compiled import CompiledModel, ModelState
from compd.model.reach import check_reachable
from compd.service.store.unreadable import finite, json_int, set_aside, whole

if TYPE_CHECKING:
    from compd.service.config.loading import Config
    from compd.service.loop.clock import Clock
    from compd.service.loop.slots import ModelSlot

log = structlog.get_logger("compd.service.store.state")

STATE_FILE = "state.json"
MODELS_DIR = "models"
CURRENT_MODEL = "current-model"
#: The model ``current-model`` named before the last ``compd model load`` (empty: the config's).
PREVIOUS_MODEL = "previous-model"
FORMAT = "compd.state/1"
#: The times a state may carry (s since the epoch, up to the year 5138): beyond, it is corrupt.
MAX_UNIX_S = 1e11
#: The tick counter's bound: 2^53, the largest whole number a float holds exactly.
MAX_TICKS = 2**53


class StateError(CompdError):
    """A state file that cannot be used (malformed, other format); the daemon starts fresh."""


@dataclass(frozen=True, eq=False)
class SavedState:
    """What survives a restart: model identity, model state, written offsets, tick counter."""

    model_sha256: str
    model_name: str
    saved_at_unix_s: float
    model_state: ModelState
    offsets_um: Mapping[str, float]
    ticks: int
    #: Real (unscaled) time of the save: a time-scaled run's clock runs ahead of it.
    saved_real_unix_s: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "saved_real_unix_s": self.saved_real_unix_s,
            "format": FORMAT,
            "model_sha256": self.model_sha256,
            "model_name": self.model_name,
            "saved_at_unix_s": self.saved_at_unix_s,
            "model_state": self.model_state.to_dict(),
            "offsets_um": dict(self.offsets_um),
            "ticks": self.ticks,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SavedState:
        """The state ``data`` holds; :class:`StateError` naming the key of anything unusable.

        Every number must be finite and in its range: the daemon writes none
        other (``allow_nan=False``), so anything else is a corrupt file.
        """
        if data.get("format") != FORMAT:
            raise StateError(f"state format {shorten(data.get('format'))} is not {FORMAT!r}")
        try:
            real = data.get("saved_real_unix_s")
            return cls(
                model_sha256=str(data["model_sha256"]),
                model_name=str(data["model_name"]),
                saved_at_unix_s=finite(data["saved_at_unix_s"], "saved_at_unix_s", 0, MAX_UNIX_S),
                model_state=_model_state(data["model_state"]),
                offsets_um={
                    str(k): finite(v, f"offsets_um.{str(k)[:40]}")
                    for k, v in data["offsets_um"].items()
                },
                ticks=whole(data["ticks"], "ticks", 0, MAX_TICKS),
                saved_real_unix_s=None
                if real is None
                else finite(real, "saved_real_unix_s", 0, MAX_UNIX_S),
            )
        except (KeyError, TypeError, ValueError, OverflowError, AttributeError, ModelError) as exc:
            raise StateError(f"state is malformed ({exc})") from exc


def _model_state(data: Any) -> ModelState:
    state = ModelState.from_dict(data)
    if not all(np.isfinite(a).all() for a in (state.z, state.reference, state.residual)):
        raise ValueError("model_state holds NaN or infinity (or a number beyond any float)")
    return state


@dataclass(frozen=True)
class Resume:
    """Whether to resume a saved state, and why (logged at start)."""

    resume: bool
    reason: str


def save_state(state_dir: Path, saved: SavedState) -> Path:
    path = state_dir / STATE_FILE
    write_atomic(path, json.dumps(saved.to_dict(), allow_nan=False).encode())
    return path


def load_state(state_dir: Path) -> SavedState | None:
    """The saved state, or ``None`` if there is none; :class:`StateError` if it is unusable."""
    path = state_dir / STATE_FILE
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise StateError(f"{path}: cannot read ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise StateError(f"{path}: not text ({exc.reason} at byte {exc.start})") from exc
    try:
        data = json.loads(text, parse_int=json_int)
    except ValueError as exc:  # json.JSONDecodeError
        raise StateError(f"{path}: not JSON ({exc})") from exc
    except RecursionError as exc:  # json's parser recurses per [ or {
        raise StateError(f"{path}: not a state file (arrays nested too deeply to parse)") from exc
    if not isinstance(data, dict):
        raise StateError(f"{path}: expected a JSON object")
    return SavedState.from_dict(data)


def resume_decision(
    saved: SavedState | None,
    model_sha256: str,
    compiled: CompiledModel,
    now_unix_s: float,
    max_age_s: float,
    *,
    real_now_unix_s: float | None = None,
    time_scale: float = 1.0,
    max_offsets_um: Mapping[str, float] | None = None,
    input_ranges: Mapping[str, tuple[float, float]] | None = None,
) -> Resume:
    """Resume ``saved`` only if it is this model's (sha256 and shape) and younger than ``max_age_s``.

    The age is machine time: on a clock ``time_scale`` times faster than real
    time (a simulated machine), the real time since the save times the scale.
    With ``max_offsets_um`` (axis -> clamp), a saved offset that is not finite
    or lies beyond its axis's clamp makes the whole state suspect: not resumed.
    A model state the model cannot reach from ``input_ranges`` (the calibration's,
    :mod:`compd.model.reach`) is not resumed either.
    """
    if saved is None:
        return Resume(False, "no saved state")
    if saved.model_sha256 != model_sha256:
        return Resume(False, f"saved state belongs to model {saved.model_sha256[:12]}")
    age_s = now_unix_s - saved.saved_at_unix_s
    if time_scale != 1.0 and real_now_unix_s is not None and saved.saved_real_unix_s is not None:
        age_s = (real_now_unix_s - saved.saved_real_unix_s) * time_scale
    if not math.isfinite(age_s):  # NaN passes every comparison below
        return Resume(False, f"saved state's age is {age_s}: its time is not a finite number")
    if age_s < 0:
        # The wall clock was set back, or the state was saved by a time-scaled run
        # (``compd run --time-scale``), whose clock runs ahead of real time.
        return Resume(False, f"saved state is stamped {-age_s:.0f} s in the future")
    if age_s > max_age_s:
        return Resume(False, f"saved state is {age_s:.0f} s old (limit {max_age_s:g} s)")
    try:
        compiled.check_state(saved.model_state)
        check_reachable(compiled, saved.model_state, input_ranges or {})  # not 1e300
    except ModelError as exc:
        return Resume(False, f"saved state does not fit the model: {exc}")
    for axis, limit_um in (max_offsets_um or {}).items():
        offset_um = saved.offsets_um.get(axis, 0.0)
        if not abs(offset_um) <= limit_um:  # NaN too
            return Resume(
                False, f"saved offset {axis} = {offset_um:g} um is beyond ±{limit_um:g} um"
            )
    return Resume(True, f"saved state is {age_s:.0f} s old")


def install_model(state_dir: Path, source: Path) -> Path:
    """Copy a model file into ``state_dir/models/<sha256>.yaml`` and point ``current-model`` at it.

    Both writes are atomic, so a daemon (re)starting meanwhile sees the old
    model or the new one. Returns the installed path.
    """
    return install_model_bytes(state_dir, source.read_bytes())


def install_model_bytes(state_dir: Path, content: bytes, config_model: Path | None = None) -> Path:
    """:func:`install_model` for a model file's bytes (as a client sent them to the daemon).

    The bytes of ``config_model`` (the config's own model) are not copied: the
    next start picks it again as the config's (no ``current-model``), and
    ``config_model`` is returned. Either way ``previous-model`` remembers the
    model that was picked before, for ``compd model load --previous``.
    """
    sha256 = hashlib.sha256(content).hexdigest()
    own = config_model is not None and _sha256_of(config_model) == sha256
    installed = config_model if own and config_model else state_dir / MODELS_DIR / f"{sha256}.yaml"
    if not own and not installed.exists():
        write_atomic(installed, content)
    current = "\n" if own else f"{MODELS_DIR}/{installed.name}\n"
    try:
        before = (state_dir / CURRENT_MODEL).read_text(errors="replace")  # corrupt: replaced
    except FileNotFoundError:
        before = "\n"  # the config's own model ran
    if before.strip() != current.strip():  # loading the same model again keeps the way back
        write_atomic(state_dir / PREVIOUS_MODEL, before.encode())
    if own:
        (state_dir / CURRENT_MODEL).unlink(missing_ok=True)
    else:
        write_atomic(state_dir / CURRENT_MODEL, current.encode())
    return installed


def install_sidecars(state_dir: Path, sidecars: Mapping[str, bytes]) -> list[Path]:
    """Each residual forest a model file names (``MODEL.residual.npz``) beside its installed copy.

    An installed model is ``models/<sha256>.yaml`` and names its forest beside
    it: without it the next start would refuse the model (and set it aside).
    A file of that name already there with the same bytes is kept; with other
    bytes (another installed model's forest) the load is refused, since
    replacing it would break that model. Returns the files written.
    """
    written = []
    for name, content in sidecars.items():
        if not name.endswith(".npz") or name in (".", "..") or any(c in name for c in "/\\\x00"):
            raise CompdError(f"a model's forest is a .npz file name with no folder, not {name!r}")
        target = state_dir / MODELS_DIR / name
        try:
            existing: bytes | None = target.read_bytes()
        except FileNotFoundError:
            existing = None
        if existing == content:
            continue
        if existing is not None:
            raise CompdError(
                f"{target} holds another installed model's forest; nothing was installed. Write "
                "the stacked model under a name of its own (compd residual --out NAME.yaml names "
                "its forest NAME.residual.npz)"
            )
        write_atomic(target, content)
        written.append(target)
    return written


def _sha256_of(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def previous_model(state_dir: Path, config_model: Path | None) -> Path | None:
    """The model that ran before the last ``compd model load`` (``config_model`` if the config's).

    ``None`` if no model was ever loaded here, or the file it names is gone.
    """
    try:
        # Not UTF-8 (a corrupt file): a name no file has, so none.
        name = (state_dir / PREVIOUS_MODEL).read_text(errors="replace").strip()
    except FileNotFoundError:
        return None
    if not name:
        return config_model
    path = state_dir / name
    return path if path.is_file() else None


def installed_models(state_dir: Path) -> list[Path]:
    """Every model file ``compd model load`` installed in ``state_dir``, oldest first."""
    models = state_dir / MODELS_DIR
    if not models.is_dir():
        return []
    return sorted(models.glob("*.yaml"), key=lambda p: (p.stat().st_mtime, p.name))


def installed_model(state_dir: Path) -> Path | None:
    """The model last installed with ``compd model load``, if any."""
    try:
        # Not UTF-8 (a corrupt file): a name no file has, so the config's model starts.
        name = (state_dir / CURRENT_MODEL).read_text(errors="replace").strip()
    except FileNotFoundError:
        return None
    path = state_dir / name
    return path if path.is_file() else None


def reinstate_model(state_dir: Path, model_path: Path) -> None:
    """Make ``model_path`` the model the next start picks, after the installed one failed.

    A model installed under ``state_dir/models`` becomes ``current-model``
    again; any other (the config's own model) is picked by removing
    ``current-model``. Either way the failed model is not started again.
    """
    models = (state_dir / MODELS_DIR).resolve()
    if model_path.resolve().parent == models:
        write_atomic(state_dir / CURRENT_MODEL, f"{MODELS_DIR}/{model_path.name}\n".encode())
    else:
        (state_dir / CURRENT_MODEL).unlink(missing_ok=True)


def resumable_state(
    config: Config, slot: ModelSlot, clock: Clock, now_unix_s: float
) -> SavedState | None:
    """The saved state to resume from, if it belongs to this model and is recent and sane enough."""
    try:
        saved = load_state(config.state_dir)
    except StateError as exc:
        set_aside_state(config.state_dir / STATE_FILE, str(exc))
        saved = None
    decision = resume_decision(
        saved,
        slot.sha256,
        slot.compiled,
        now_unix_s,
        config.doc.state.resume_max_age_s,
        real_now_unix_s=time.time(),
        # A scaled clock's time_scale; virtual time (None, or none given) counts as real.
        time_scale=getattr(clock, "time_scale", None) or 1.0,
        max_offsets_um={axis: out.max_offset_um for axis, out in config.doc.outputs.items()},
        input_ranges=calibration_ranges(slot),
    )
    log.info(
        "model",
        name=slot.compiled.name,
        sha256=slot.sha256,
        path=slot.model_file.path,
        resume=decision.resume,
        reason=decision.reason,
    )
    return saved if decision.resume else None


def set_aside_state(path: Path, reason: str) -> None:
    """The unreadable state file ``path`` set aside, in one ERROR line; the daemon starts without it."""
    try:
        target = set_aside(path)
    except FileNotFoundError:
        target = None  # gone (or never there: a state directory that cannot be read)
    except OSError as exc:
        log.error(
            "saved state cannot be read, nor set aside; starting without it",
            file=str(path),
            reason=reason,
            error=str(exc),
        )
        return
    log.error(
        "saved state cannot be read: set aside; starting without it",
        file=str(path),
        set_aside_as=None if target is None else str(target),
        reason=reason,
    )


def calibration_ranges(slot: ModelSlot) -> Mapping[str, tuple[float, float]]:
    """The ``[min, max]`` of each signal in the model's calibration data (none recorded: empty)."""
    calibration = slot.model_file.doc.provenance.calibration
    return {} if calibration is None else calibration.ranges
