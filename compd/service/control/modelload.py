"""Models into a running daemon: at start-up, and over the control socket, never stalling the loop.

``compd model load`` reads its model file itself and sends the bytes; the
daemon never opens a path a client names, so the socket cannot be used to
make it read files with its rights (``/etc/shadow``, its own secrets).
Validation (parse, compile, the limits of :mod:`compd.model.limits`, the
fit with the config) and the install into the state directory run in a
worker thread, one load at a time and under a time limit, while the 1 Hz
tick and SIGTERM go on being served by the event loop.

A model that later fails while running is unloaded by the loop
(:class:`~compd.service.loop.compensator.Compensator`); :meth:`ModelLoader.failed` then makes
the model it restored the one the next start picks, so a bad model is never
started again by a restart. At start-up an installed model that is refused
falls back on the config's model, with an ERROR naming both; one that cannot
be read at all is also set aside (:func:`startup_slots`).
"""

from __future__ import annotations

import asyncio
import base64
import binascii
import contextlib
import dataclasses
import hashlib
import re
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import structlog

from compd.errors import CompdError, ConfigFileError, InputFileError, ModelFileError
from compd.files.modelfile import ModelFile, parse_model_bytes
from compd.files.sidecar import residual_files
from compd.files.yamlplace import MAX_YAML_BYTES, read_limited, shorten
from compd.service.config.loading import Config
from compd.service.config.modelcheck import check_model
from compd.service.loop.slots import ModelSlot
from compd.service.store.state import (
    MODELS_DIR,
    install_model_bytes,
    install_sidecars,
    installed_model,
    reinstate_model,
)
from compd.service.store.unreadable import set_aside

log = structlog.get_logger("compd.service.control.modelload")
T = TypeVar("T")

#: Longest a load may take to validate and install before it is refused (s);
#: within the model limits it takes well under a second.
LOAD_TIMEOUT_S = 30.0
#: An installed model's name: the sha256 of its bytes.
SHA256 = re.compile(r"[0-9a-f]{64}")


def slot_from_bytes(
    config: Config, raw: bytes, name: str | Path, loaded_at_unix_s: float
) -> ModelSlot:
    """Validate, compile (at the config's period) and check model-file bytes against ``config``."""
    if config.logger:
        raise ConfigFileError(
            config.path,
            "this config is a data logger (no 'outputs', no 'model'): it has no model to switch",
            where="outputs",
            fix="Add 'model' and 'outputs' to the config and restart compd to compensate with it",
        )
    return slot_from_file(config, parse_model_bytes(raw, name), loaded_at_unix_s)


def slot_from_file(config: Config, model_file: ModelFile, loaded_at_unix_s: float) -> ModelSlot:
    """:func:`slot_from_bytes` for a model file already read."""
    model_file.check_plausible()  # what `compd model check` refuses, the daemon never runs
    # The file's difference equations at the period, stepped with numpy alone: a file that
    # would need converting (scipy) is refused with the command that precompiles it.
    compiled = model_file.compile(config.doc.period_s, convert=False)
    check_model(config, model_file, compiled)
    return ModelSlot(model_file, compiled, loaded_at_unix_s)


def warn_unguarded(config: Config, slot: ModelSlot) -> None:
    """One WARNING per axis whose offset the running model leaves to the clamp alone.

    A model file without a calibrated output range (written by hand or by an
    older compd) runs, but the envelope (:mod:`compd.service.loop.envelope`)
    has nothing to judge its offset by: said at start and at each load, not
    found out when an extrapolated offset is written.
    """
    if config.doc.safety.envelope_margin is None:
        return
    for axis, output in config.doc.outputs.items():
        if slot.model_file.output_range(output.model_output) is None:
            log.warning(
                "the model file records no calibrated range of this output: the clamp alone "
                "judges the axis's offset",
                axis=axis,
                output=output.model_output,
                model=str(slot.model_file.path),
                fix="refit with compd fit to record one",
            )


def installed_slot(
    config: Config,
    raw: bytes,
    name: str | Path,
    sidecars: Mapping[str, bytes],
    loaded_at_unix_s: float,
) -> ModelSlot:
    """:func:`slot_from_bytes` for a model a client sent (``name``: its name, for messages), read
    where it will be installed.

    Its residual forests (sent with it, or installed with it before) are read
    from the state directory's ``models/``, beside ``models/<sha256>.yaml``,
    never from a path the client names; those sent and not taken are removed.
    """
    path = config.state_dir / MODELS_DIR / f"{hashlib.sha256(raw).hexdigest()}.yaml"
    written = install_sidecars(config.state_dir, sidecars)
    try:
        slot = slot_from_bytes(config, raw, path, loaded_at_unix_s)
    except BaseException as exc:
        for file in written:
            file.unlink(missing_ok=True)
        if isinstance(exc, InputFileError):
            raise _as_named(exc, path, str(name)) from exc
        raise
    named = set(residual_files(slot.model_file.doc))
    for file in written:
        if file.name not in named:
            file.unlink(missing_ok=True)
    return slot


def _as_named(exc: InputFileError, path: Path, name: str) -> InputFileError:
    """``exc`` naming the model as the client did, not by where the daemon reads it."""
    if exc.where.endswith(".residual.file"):
        return ModelFileError(
            name,
            f"its residual forest was not sent with it ({exc.message})",
            where=exc.where,
            fix="Load it with 'compd model load FILE', which sends the .npz beside FILE",
        )

    def swap(text: str) -> str:
        return text.replace(str(path), name)

    return type(exc)(
        name if exc.path == str(path) else exc.path,
        swap(exc.message),
        where=exc.where,
        fix=swap(exc.fix),
    )


def load_slot(config: Config, path: Path, loaded_at_unix_s: float) -> ModelSlot:
    """:func:`slot_from_bytes` for a file (a regular file, size-limited); raises on any problem."""
    return slot_from_bytes(config, read_limited(path, ModelFileError), path, loaded_at_unix_s)


def startup_slots(config: Config, now_unix_s: float) -> tuple[ModelSlot | None, ModelSlot | None]:
    """The model to start with and the one to fall back on if it fails while running.

    A data logger (:attr:`Config.logger`) starts with none, whatever is installed.

    The model installed with ``compd model load`` comes first, with the
    config's as its fallback; an installed model that is refused is logged,
    un-installed, and the config's model starts instead. One that cannot even
    be read (a corrupt file: not a model file, a number no model holds, bytes
    that are not those installed under their sha256) is set aside as well
    (renamed ``<sha256>.yaml.corrupt-<UTC time>``, nothing deleted).
    """
    if config.model_path is None:
        return None, None
    installed = installed_model(config.state_dir)
    if installed is None:
        return load_slot(config, config.model_path, now_unix_s), None
    try:
        model_file = read_installed(installed)
    except ModelFileError as exc:
        _set_aside_installed(config.state_dir, installed, config.model_path, str(exc))
        reinstate_model(config.state_dir, config.model_path)
        return load_slot(config, config.model_path, now_unix_s), None
    try:
        slot = slot_from_file(config, model_file, now_unix_s)
    except CompdError as exc:
        log.error(
            "the installed model is refused; starting with the config's model",
            installed=str(installed),
            config_model=str(config.model_path),
            error=str(exc),
        )
        reinstate_model(config.state_dir, config.model_path)
        return load_slot(config, config.model_path, now_unix_s), None
    log.info(
        "starting with the model installed by 'compd model load', not the config's",
        installed=str(installed),
        config_model=str(config.model_path),
    )
    try:
        fallback = load_slot(config, config.model_path, now_unix_s)
    except CompdError as exc:
        log.warning("the config's model cannot be a fallback", error=str(exc))
        fallback = None
    return slot, fallback


def read_installed(path: Path) -> ModelFile:
    """An installed model, read and parsed; ModelFileError if it cannot be (corrupt).

    A file named by a sha256 (as :func:`~compd.service.store.state.install_model_bytes`
    names them) must hold the bytes of that sha256.
    """
    raw = read_limited(path, ModelFileError)
    model_file = parse_model_bytes(raw, path)
    if SHA256.fullmatch(path.stem) and model_file.sha256 != path.stem:
        raise ModelFileError(
            path,
            f"its bytes are not those installed (their sha256 is {model_file.sha256[:12]}...)",
            fix="Load the model again with 'compd model load'",
        )
    return model_file


def _set_aside_installed(state_dir: Path, installed: Path, config_model: Path, reason: str) -> None:
    """The unreadable installed model set aside, in one ERROR line naming both files and why.

    Only a file in the state directory's ``models/`` is renamed: ``current-model``
    may name any path, and the daemon renames none but its own files.
    """
    target: str | None = None
    if installed.resolve().parent != (state_dir / MODELS_DIR).resolve():
        reason = f"{reason}; not in {state_dir / MODELS_DIR}, so left where it is"
    else:
        try:
            target = str(set_aside(installed))
        except OSError as exc:
            reason = f"{reason}; cannot set it aside ({exc.strerror})"
    aside = ": set aside" if target is not None else ""
    log.error(
        f"the installed model cannot be read{aside}; starting with the config's model",
        installed=str(installed),
        set_aside_as=target,
        config_model=str(config_model),
        reason=reason,
    )


def load_request(
    raw: bytes, name: str | Path, sidecars: Mapping[str, bytes] | None = None
) -> dict[str, Any]:
    """The control-socket request that loads the model file ``raw`` (``name`` for messages),
    with the residual forests it names (``sidecars``: file name -> bytes)."""
    request: dict[str, Any] = {"cmd": "load", "name": str(name), "model_base64": _b64(raw)}
    if sidecars:
        request["sidecars_base64"] = {file: _b64(content) for file, content in sidecars.items()}
    return request


def _b64(content: bytes) -> str:
    return base64.b64encode(content).decode("ascii")


def request_sidecars(message: dict[str, Any]) -> dict[str, bytes]:
    """The residual forests a ``load`` request carries (file name -> bytes); none is no error."""
    sent = message.get("sidecars_base64", {})
    if not isinstance(sent, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in sent.items()
    ):
        raise CompdError('"sidecars_base64" is an object of file name -> base64 text')
    try:
        return {file: base64.b64decode(text, validate=True) for file, text in sent.items()}
    except binascii.Error as exc:
        raise CompdError(f"sidecars_base64 is not base64 ({exc})") from exc


def request_bytes(message: dict[str, Any]) -> tuple[bytes, str]:
    """The model bytes and the client's name for them from a ``load`` request."""
    if "path" in message:
        raise CompdError(
            "the daemon does not read files named by a client: send the model's bytes "
            "(compd model load FILE does)"
        )
    encoded = message.get("model_base64")
    if not isinstance(encoded, str):
        raise CompdError('a load request needs "model_base64": the model file, base64-encoded')
    if len(encoded) > 4 * (MAX_YAML_BYTES // 3 + 1):
        raise CompdError(f"the model file is larger than {MAX_YAML_BYTES} bytes")
    try:
        raw = base64.b64decode(encoded, validate=True)
    except binascii.Error as exc:
        raise CompdError(f"model_base64 is not base64 ({exc})") from exc
    name = message.get("name")
    return raw, shorten(name, 200).strip("'\"") if isinstance(name, str) else "<sent model>"


class ModelLoader:
    """``load`` requests, validated and installed off the event loop, one at a time."""

    def __init__(self, config: Config, wall: Callable[[], float]) -> None:
        self.config = config
        self.wall = wall
        self.timeout_s = LOAD_TIMEOUT_S
        self._busy: asyncio.Future[ModelSlot] | None = None

    async def accept(self, message: dict[str, Any]) -> ModelSlot:
        """The new model's slot, installed as the next start's model; raises CompdError if refused."""
        raw, name = request_bytes(message)
        sidecars = request_sidecars(message)
        if self._busy is not None and not self._busy.done():
            raise CompdError("another model load is still being checked; try again shortly")
        self._busy = in_daemon_thread(installed_slot, self.config, raw, name, sidecars, self.wall())
        try:
            async with asyncio.timeout(self.timeout_s):
                # shield: a timed-out check finishes in its thread, its result dropped.
                slot = await asyncio.shield(self._busy)
        except TimeoutError:
            error = f"checking the model took longer than {self.timeout_s:g} s"
            log.error("model refused; the running model goes on", name=name, error=error)
            raise CompdError(f"{name}: {error}; it was not loaded") from None
        except CompdError as exc:
            log.error("model refused; the running model goes on", name=name, error=str(exc))
            raise
        # Installed only once accepted (an overrun check is never installed), so
        # the next start runs it; an fsync or two, off the loop as well.
        try:
            installed = await in_daemon_thread(
                install_model_bytes, self.config.state_dir, raw, self.config.model_path
            )
        except OSError as exc:
            raise CompdError(
                f"cannot install the model in {self.config.state_dir} ({exc.strerror})"
            ) from exc
        slot.model_file = dataclasses.replace(slot.model_file, path=str(installed))
        warn_unguarded(self.config, slot)
        return slot

    async def keep(self, running: ModelSlot) -> None:
        """Make ``running`` the model the next start picks (``current-model``), off the loop.

        Loading the model that runs is a no-op for the loop, but the installed
        model may have drifted from it (an old client installed another while
        it could not reach this daemon): the next start must not switch.
        """
        try:
            await in_daemon_thread(
                reinstate_model, self.config.state_dir, Path(running.model_file.path)
            )
        except OSError as exc:
            raise CompdError(
                f"cannot make the running model the installed one in {self.config.state_dir} "
                f"({exc.strerror})"
            ) from exc

    def failed(self, failed: ModelSlot, restored: ModelSlot) -> None:
        """A model failed while running: the next start picks ``restored``, not it.

        Called from the tick, rarely: one small atomic write is cheaper than a thread.
        """
        try:
            reinstate_model(self.config.state_dir, Path(restored.model_file.path))
        except OSError as exc:
            log.error("cannot un-install the failed model", error=str(exc), model=failed.sha256)


def in_daemon_thread(function: Callable[..., T], *args: object) -> asyncio.Future[T]:
    """``function(*args)`` in a daemon thread, as a future of the running loop.

    Not the default executor: its threads are joined when the loop closes,
    so a check that overran its time limit would hold up the shutdown.
    """
    loop = asyncio.get_running_loop()
    future: asyncio.Future[T] = loop.create_future()

    def settle(result: T | None, error: BaseException | None) -> None:
        if future.done():
            return
        if error is not None:
            future.set_exception(error)
        else:
            future.set_result(result)  # type: ignore[arg-type]

    def work() -> None:
        try:
            result, error = function(*args), None
        except BaseException as exc:  # handed to the awaiting coroutine
            result, error = None, exc
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
            loop.call_soon_threadsafe(settle, result, error)

    threading.Thread(target=work, name="compd-model-check", daemon=True).start()
    return future
