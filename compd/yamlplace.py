"""Where in a YAML file a problem is: shared by the model-file and config-file loaders.

Both loaders validate with pydantic and report each problem as
``FILE: line N (a.b[2].c): what is wrong. fix``. pydantic knows the dotted
place (``loc``) but not the line; the YAML node tree (``yaml.compose``) knows
the line. This module joins the two, so the two loaders word their messages
the same way. It also resolves the file paths those files name
(:func:`resolve_path`), relative to the naming file or inside the installed
package (``bundled:NAME``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from compd.errors import InputFileError


def parse_yaml(
    text: str, path: object, error: type[InputFileError]
) -> tuple[Any, yaml.Node | None]:
    """The document and its node tree (for line numbers); a syntax error names the file and line.

    The one place compd reads YAML text, so every loader (model, config,
    effect catalogue) words a syntax error the same way.
    """
    try:
        return yaml.safe_load(text), yaml.compose(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise error(path, f"not valid YAML: {problem}", where=where) from exc


#: The fix to suggest per pydantic error type.
FIXES = {
    "extra_forbidden": "Remove the key or fix its spelling",
    "missing": "Add the key",
    "literal_error": "Use one of the allowed values",
    "float_parsing": "Give a number",
    "finite_number": "Give a finite number",
    "int_parsing": "Give a whole number",
    "bool_parsing": "Give true or false",
    "greater_than": "Give a larger value",
    "greater_than_equal": "Give a larger value",
    "less_than_equal": "Give a smaller value",
}


def describe(error: Any) -> str:
    """One pydantic error as a sentence fragment (``unknown key 'x'``, ``... (got 3)``)."""
    kind = error["type"]
    if kind == "extra_forbidden":
        return f"unknown key {error['loc'][-1]!r}"
    if kind == "missing":
        return f"required key {error['loc'][-1]!r} is missing"
    message = str(error["msg"])
    if message.startswith("Value error, "):
        message = message[len("Value error, ") :]
    shown = error.get("input")
    if not isinstance(shown, dict | list):
        message = f"{message} (got {shown!r})"
    return message


def where(root: yaml.Node | None, location: tuple[str | int, ...]) -> str:
    """``line N (a.b[2].c)``: the dotted place, with the YAML line of the deepest node found."""
    dotted = ""
    for part in location:
        if isinstance(part, int):
            dotted += f"[{part}]"
        else:
            dotted += f".{part}" if dotted else str(part)
    node, line = root, None
    for part in location:
        if isinstance(node, yaml.MappingNode):
            match = next((v for k, v in node.value if k.value == part), None)
            if match is None:
                key = next((k for k, _ in node.value if k.value == part), None)
                line = key.start_mark.line + 1 if key is not None else line
                break
            node = match
        elif (
            isinstance(node, yaml.SequenceNode) and isinstance(part, int) and part < len(node.value)
        ):
            node = node.value[part]
        else:
            break
        line = node.start_mark.line + 1
    if line is None and root is not None:
        line = root.start_mark.line + 1
    return f"line {line} ({dotted})" if dotted else f"line {line}"


#: Prefix of a path inside the bundled examples (``config/``, installed as ``compd.bundled``).
BUNDLED = "bundled:"


def resolve_path(text: str | Path, base_dir: Path) -> Path:
    """A path named in a YAML file: ``bundled:NAME``, absolute, ``~/...``, or relative to ``base_dir``.

    ``bundled:`` resolves through the installed package, never the checkout,
    so a bundled config runs the same from a wheel as from a clone.
    """
    text = str(text)
    if text.startswith(BUNDLED):
        return Path(str(resources.files("compd.bundled").joinpath(text[len(BUNDLED) :])))
    path = Path(text).expanduser()
    return path if path.is_absolute() else base_dir / path
