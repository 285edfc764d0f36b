"""``--set KEY=VALUE``: a config key changed from the command line, the file left as it is.

``compd run --config bundled:simulated.yaml --set drivers.plc.settings.port=15021``
runs the quick start's config with its PLC on another port: the driver
connects there, and the simulated machine (which serves the drivers' own
host and port) listens there. ``KEY`` is the dotted path of a key in the
YAML (a key whose name holds a dot cannot be set this way); ``VALUE`` is
YAML (``15021``, ``true``, ``[1, 2]``, ``{min: 0}``). Each override replaces
the key's value, or adds the key where the section lacks it, before the
config is checked: a value the section does not take is refused like one
written in the file, naming the key and the fix. The daemon keeps the
overrides with its config, so a reload (SIGHUP) re-reads the file with them.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from compd.errors import ConfigFileError
from compd.files.yamlplace import parse_yaml

_FIX = "Give KEY=VALUE: a dotted key of the config, then YAML, e.g. drivers.plc.settings.port=15021"


def apply_overrides(data: Any, overrides: Iterable[str], path: Path) -> Any:
    """``data`` (the config's YAML, a mapping) with each ``KEY=VALUE`` set, in order; ``data`` untouched."""
    for override in overrides:
        key, sep, text = override.partition("=")
        keys = key.strip().split(".")
        if not sep or not all(keys):
            raise ConfigFileError(path, f"--set {override!r} is not KEY=VALUE", fix=_FIX)
        value, _ = parse_yaml(text, f"--set {key}", ConfigFileError)
        data = _set(data, keys, value, path, override)
    return data


def _set(data: Any, keys: list[str], value: Any, path: Path, override: str) -> Any:
    """A copy of ``data`` with ``keys`` (a path of mapping keys) set to ``value``."""
    if not isinstance(data, dict):
        raise ConfigFileError(
            path,
            f"--set {override!r}: the key above {keys[0]!r} is not a section",
            fix="Name a key inside a section (mapping) of the config",
        )
    head, rest = keys[0], keys[1:]
    inner = value if not rest else _set(data.get(head, {}), rest, value, path, override)
    return data | {head: inner}
