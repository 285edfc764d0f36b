"""How to start the daemon a config belongs to, for the message that says it is not running.

``systemctl start compd`` is only right where that unit is installed and runs
this config: ``compd.service`` runs ``/etc/compd/compd.yaml``, and
``compd@NAME.service`` runs ``/etc/compd/NAME.yaml`` (``deploy/``). Anywhere
else (a config in a checkout, no unit installed) the hint is the command
that starts it by hand.
"""

from __future__ import annotations

from pathlib import Path

#: Where systemd looks for unit files, in its order (systemd.unit(5), system units).
UNIT_DIRS = (
    Path("/etc/systemd/system"),
    Path("/run/systemd/system"),
    Path("/usr/local/lib/systemd/system"),
    Path("/usr/lib/systemd/system"),
    Path("/lib/systemd/system"),
)

#: Where the units in ``deploy/`` read their configs.
CONFIG_DIR = Path("/etc/compd")


def start_hint(config: Path, unit_dirs: tuple[Path, ...] = UNIT_DIRS) -> str:
    """``start it with: ...``: the systemd unit that runs ``config`` if one is installed, else ``compd run``."""
    config = Path(config).absolute()

    def installed(unit: str) -> bool:
        return any((directory / unit).is_file() for directory in unit_dirs)

    if config.parent == CONFIG_DIR and config.suffix == ".yaml":
        if config.stem == "compd" and installed("compd.service"):
            return "start it with: systemctl start compd"
        if installed("compd@.service"):
            return f"start it with: systemctl start compd@{config.stem}"
    return f"start it with: compd run --config {config}"
