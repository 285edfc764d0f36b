"""``compd model list``, ``compd model load --previous``, and what ``compd run`` says it runs.

A model put in service with ``compd model load`` stays in the config's state
directory (``models/<sha256>.yaml``, ``current-model``) and runs at every
later start instead of the config's ``model``. These say so.
"""

from __future__ import annotations

import argparse
import asyncio
import time
from pathlib import Path

from compd.errors import CompdError, ControlError
from compd.files.modelfile import load_model
from compd.service.config.loading import Config
from compd.service.control.socket import request
from compd.service.store.state import installed_model, installed_models, previous_model


def previous_or_refuse(config: Config) -> Path:
    """The model file ``compd model load --previous`` loads; a CompdError if there is none."""
    previous = previous_model(config.state_dir, config.model_path)
    if previous is None:
        raise CompdError(
            f"no previous model in {config.state_dir}: 'compd model load' was never run with "
            f"this config (or the file it named is gone); 'compd model list --config "
            f"{config.path}' shows the models there"
        )
    return previous


def installed_notice(config: Config) -> str | None:
    """What ``compd run`` prints at start and end when it runs an installed model, else None."""
    installed = installed_model(config.state_dir)
    if installed is None or config.model_path is None:
        return None
    try:
        name = load_model(installed).model.name
    except CompdError:
        return None  # refused at start-up: the daemon falls back on the config's and logs why
    loaded = time.strftime("%Y-%m-%d %H:%M", time.localtime(installed.stat().st_mtime))
    return (
        f"model {name} installed by 'compd model load' ({loaded}, sha256 {installed.stem[:12]}), "
        f"not the config's {config.model_path.name}: 'compd model load --previous' goes back, "
        "'compd model list' shows the models"
    )


def list_command(args: argparse.Namespace) -> int:
    from rich.table import Table

    from compd.cli.serving import config_from_arg
    from compd.cli.terminal import console

    config = config_from_arg(args.config)
    if config.model_path is None:
        raise CompdError(f"{config.path} is a data logger (no 'model'): it runs no model")
    current = installed_model(config.state_dir)
    previous = previous_model(config.state_dir, config.model_path)
    running = _running_sha256(config)
    table = Table("model", "sha256", "file", "installed", "")
    for path in [config.model_path, *installed_models(config.state_dir)]:
        try:
            model_file = load_model(path)
        except CompdError as exc:
            table.add_row("?", "", str(path), "", f"unreadable: {exc}")
            continue
        is_config = path == config.model_path
        roles = []
        if model_file.sha256 == running:
            roles.append("running")
        if path == (current or config.model_path):
            roles.append("next start")
        if previous is not None and path == previous:
            roles.append("previous (load --previous)")
        installed = time.strftime("%Y-%m-%d %H:%M", time.localtime(path.stat().st_mtime))
        table.add_row(
            model_file.model.name,
            model_file.sha256[:12],
            str(path),
            "config's model" if is_config else installed,
            ", ".join(roles),
        )
    out = console()
    out.print(table)
    if running is None:
        out.print(f"no daemon runs on {config.control_socket}")
    return 0


def _running_sha256(config: Config) -> str | None:
    """The sha256 of the model the daemon runs, or None if none runs or it does not answer."""
    try:
        status = asyncio.run(request(config.control_socket, {"cmd": "status"}, timeout_s=2.0))
    except ControlError:
        return None
    model = status.get("model")
    return model.get("sha256") if isinstance(model, dict) else None
