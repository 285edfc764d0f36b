"""SIGHUP: re-read and check the config, apply what can change safely, never exit.

``systemctl reload compd`` (the unit's ``ExecReload=/bin/kill -HUP $MAINPID``),
logrotate and many operators send SIGHUP; its default action ends the
process, which would leave the machine's offsets, the state and the control
socket as a crash does. The daemon takes it instead (:meth:`Reloader.request`):

1. The config file is read and checked again, off the event loop (a host
   name in it may be looked up). A config with an error is refused with one
   ERROR line: the daemon runs on with the config it started with.
2. A config that differs from the running one is not applied: drivers,
   signals, outputs and safety limits change what is written to a machine,
   and are taken only by a restart, where everything is checked before the
   first write. One WARNING names the changed sections and the fix (a restart;
   a model switches without one with ``compd model load``).
   The config's model file is not a config section: one changed on disk
   while the daemon runs it is not applied either (a model switches with
   ``compd model load``, checked and blended), and one WARNING says so
   rather than "config unchanged" alone.
3. The recorder closes its file; the next tick starts a new one of the same
   run (``run_reason: reopened``), so a file moved away by logrotate is let go.
   (The logs go to stderr, the journal: there is no log file to re-open.)

One INFO line says what was done. A SIGHUP while one is under way is taken by
it. systemd is told ``RELOADING=1`` and ``READY=1`` around the work once the
daemon has said it is ready.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
from collections.abc import Callable
from pathlib import Path

import structlog

from compd.errors import RecorderError
from compd.service.config.loading import Config, load_config
from compd.service.notify import SystemdNotifier
from compd.service.recording.recorder import RecordingFiles

log = structlog.get_logger("compd.service.reload")


class Reloader:
    """Takes SIGHUP for one service: ``ready`` says whether it has told systemd READY=1."""

    def __init__(
        self,
        config: Config,
        recorder: RecordingFiles | None,
        notifier: SystemdNotifier,
        *,
        ready: Callable[[], bool],
        running: Callable[[], tuple[str, str] | None] = lambda: None,
    ) -> None:
        self.config = config
        self.recorder = recorder
        self.notifier = notifier
        self.ready = ready
        #: The running model's file path and sha256 (None: none runs).
        self.running = running
        #: Reloads done (each SIGHUP taken, whatever came of it).
        self.done = 0
        self._task: asyncio.Task[None] | None = None

    def request(self) -> None:
        """Start a reload on the running loop (a signal handler's callback); one at a time."""
        if self._task is not None and not self._task.done():
            log.info("reload: one is under way and takes this SIGHUP as well")
            return
        self._task = asyncio.get_running_loop().create_task(self._reload())

    async def close(self) -> None:
        """At shutdown: a reload under way is cancelled (its config read is dropped)."""
        if self._task is not None and not self._task.done():
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    async def _reload(self) -> None:
        ready = self.ready()
        if ready:
            self.notifier.reloading(f"reloading {self.config.path}")
        try:
            config = self._config_outcome(
                await asyncio.to_thread(load_config, self.config.path, self.config.overrides)
            )
        except Exception as exc:  # a config that cannot be read; never the daemon's end
            log.error(
                "reload: the config is refused; running on with the config it started with",
                config=str(self.config.path),
                error=str(exc),
            )
            config = "refused (error logged)"
        await asyncio.to_thread(self._check_model_file)
        recorder = self._reopen_recorder()
        self.done += 1
        log.info("reloaded", config=config, recorder=recorder)
        if ready:
            self.notifier.ready(f"reloaded: config {config}; recorder {recorder}")

    def _config_outcome(self, new: Config) -> str:
        """What the re-read config means for the running daemon, logged if it changed."""
        old = self.config.doc
        changed = [
            name for name in type(old).model_fields if getattr(old, name) != getattr(new.doc, name)
        ]
        if not changed:
            return "unchanged"
        log.warning(
            "reload: the config changed in what only a restart applies; running on with the "
            "config it started with",
            config=str(self.config.path),
            changed=changed,
            fix="Restart compd to apply it (systemctl restart compd); a model switches "
            "without a restart with 'compd model load FILE'",
        )
        return f"changed ({', '.join(changed)}), not applied: restart to apply"

    def _check_model_file(self) -> None:
        """One WARNING when the running model is the config's file and that file changed on disk."""
        running, path = self.running(), self.config.model_path
        if running is None or path is None:
            return
        running_path, running_sha256 = running
        if Path(running_path).resolve() != path.resolve():
            return  # an installed model runs: the config's file is its fallback
        try:
            on_disk = hashlib.sha256(path.read_bytes()).hexdigest()
        except OSError as exc:
            on_disk = f"unreadable ({exc.strerror})"
        if on_disk == running_sha256:
            return
        log.warning(
            "reload: the model file changed on disk; running on with the model it loaded",
            model=str(path),
            running_sha256=running_sha256,
            on_disk_sha256=on_disk,
            fix=f"Switch to it with 'compd model load {path}' (checked, then blended in)",
        )

    def _reopen_recorder(self) -> str:
        if self.recorder is None:
            return "off"
        try:
            closed: Path | None = self.recorder.reopen()
        except RecorderError as exc:
            log.error("reload: the recording could not be closed cleanly", error=str(exc))
            return "new file at the next tick (the last one closed with an error)"
        return "new file at the next tick" + ("" if closed is None else f" ({closed.name} closed)")
