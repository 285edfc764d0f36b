"""Paths in a model file's provenance, relative to the model file's folder, so the record travels with it.

A command records the data files as the user named them, relative to the
working directory; once written beside the model they are rewritten:

- a bundled file (``config/``, installed as ``compd.bundled``) is
  ``bundled:NAME``, unless the model itself is bundled (then its plain name);
- a file in the same tree as the model (their common folder is below a
  top-level folder such as ``/home/user`` or ``/tmp/run``) is the relative
  path from the model's folder, as ``resolve_path`` reads paths in YAML;
- anything else (another disk, a share) stays absolute: a relative path
  climbing to ``/`` would be no more portable.

The command line is rewritten the same way, word by word (each word naming an
existing file, or an absolute path), so it reads as run from the model's
folder. A model derived from a parent (``extend``, ``update``, ``residual``)
keeps the parent's entries, moved from the parent's folder to the new one.
"""

from __future__ import annotations

import os
import shlex
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from compd.files.modelschema import ProvenanceDoc
from compd.files.modelwriter import provenance_lines
from compd.files.yamlplace import BUNDLED

#: Where each path sits in a provenance record (``*``: every item of a list).
PATH_FIELDS = (
    ("data",),
    ("fit_data",),
    ("calibration", "data"),
    ("calibration", "extended_with", "*"),
    ("base_model", "data"),
    ("headline", "data"),
    ("extensions", "*", "data"),
    ("extensions", "*", "verify_data"),
    ("updates", "*", "data"),
    ("updates", "*", "probes"),
    ("updates", "*", "characteristic", "data"),
)
_BLOCK = "\nprovenance:\n"


def portable_path(text: str, model_dir: Path, base_dir: Path | None = None) -> str:
    """``text`` (a path relative to ``base_dir``, default the working directory) as seen from ``model_dir``.

    Text that names no existing file and is not absolute (a description such as
    "Horejs 2010, eq. 1") is returned unchanged, as is ``bundled:NAME``.
    """
    if text.startswith(BUNDLED) or not text:
        return text
    path = Path(text).expanduser()
    if not path.is_absolute():
        path = (base_dir or Path.cwd()) / path
        if not path.exists():
            return text
    path = Path(os.path.abspath(path))
    model_dir = Path(os.path.abspath(model_dir))
    bundled = Path(os.path.abspath(str(resources.files("compd.bundled"))))
    if path.is_relative_to(bundled) and model_dir != bundled:
        return BUNDLED + path.relative_to(bundled).as_posix()
    common = Path(os.path.commonpath([path, model_dir]))
    if len(common.parts) < 3:  # "/" or "/home": different trees
        return str(path)
    return Path(os.path.relpath(path, model_dir)).as_posix()


def portable_command(command: str, model_dir: Path, base_dir: Path | None = None) -> str:
    """A recorded command line with its file arguments (``--out=F`` too) seen from ``model_dir``."""
    try:
        words = shlex.split(command)
    except ValueError:  # not a shell line (hand-written provenance): leave it
        return command

    def one(word: str) -> str:
        option, equals, value = word.partition("=")
        if equals and option.startswith("--"):
            return f"{option}={one(value)}"
        if word.startswith("-"):
            return word
        return portable_path(word, model_dir, base_dir)

    return shlex.join(one(word) for word in words)


def portable_provenance(
    provenance: ProvenanceDoc,
    model_dir: Path,
    *,
    parent: ProvenanceDoc | None = None,
    parent_dir: Path | None = None,
) -> ProvenanceDoc:
    """``provenance`` with every path seen from ``model_dir``.

    Entries equal to ``parent``'s at the same place were recorded relative to
    ``parent_dir`` (the parent model's folder); the rest relative to the
    working directory.
    """
    record = provenance.model_dump(mode="json", by_alias=True)
    inherited = parent.model_dump(mode="json", by_alias=True) if parent is not None else {}

    def moved(where: tuple[Any, ...], text: str, convert: Callable[..., str]) -> str:
        from_parent = _get(inherited, where) == text
        return convert(text, model_dir, parent_dir if from_parent else None)

    for fields in PATH_FIELDS:
        for where in _places(record, fields):
            value = _get(record, where)
            if isinstance(value, str):
                _set(record, where, moved(where, value, portable_path))
    if isinstance(record.get("command"), str):
        record["command"] = moved(("command",), record["command"], portable_command)
    return ProvenanceDoc.model_validate(record)


def with_portable_provenance(
    yaml_text: str,
    model_path: Path,
    *,
    parent: ProvenanceDoc | None = None,
    parent_path: Path | None = None,
) -> str:
    """A model file's text (as :func:`~compd.files.modelwriter.model_to_yaml` writes it, provenance
    last) with its provenance's paths made relative to ``model_path``'s folder."""
    head, found, block = yaml_text.rpartition(_BLOCK)
    if not found:
        return yaml_text
    provenance = ProvenanceDoc.model_validate(yaml.safe_load("provenance:\n" + block)["provenance"])
    portable = portable_provenance(
        provenance,
        model_path.parent,
        parent=parent,
        parent_dir=None if parent_path is None else parent_path.parent,
    )
    return head + "\n" + "\n".join(provenance_lines(portable)) + "\n"


def write_model_text(
    path: Path,
    yaml_text: str,
    *,
    parent: ProvenanceDoc | None = None,
    parent_path: Path | None = None,
) -> None:
    """Write a model file whose provenance's paths are relative to its folder.

    Written twice: the command line names the file itself (``--out``), which
    must exist to be recognised as a path.
    """
    path.write_text(yaml_text, encoding="utf-8")
    path.write_text(
        with_portable_provenance(yaml_text, path, parent=parent, parent_path=parent_path),
        encoding="utf-8",
    )


def _places(record: dict[str, Any], fields: tuple[str, ...]) -> list[tuple[Any, ...]]:
    places: list[tuple[Any, ...]] = [()]
    for field in fields:
        grown: list[tuple[Any, ...]] = []
        for where in places:
            value = _get(record, where)
            if field == "*":
                grown += [(*where, i) for i in range(len(value))] if isinstance(value, list) else []
            elif isinstance(value, dict) and value.get(field) is not None:
                grown.append((*where, field))
        places = grown
    return places


def _get(record: Any, where: tuple[Any, ...]) -> Any:
    for key in where:
        try:
            record = record[key]
        except (KeyError, IndexError, TypeError):
            return None
    return record


def _set(record: Any, where: tuple[Any, ...], value: str) -> None:
    for key in where[:-1]:
        record = record[key]
    record[where[-1]] = value
