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

import os
import stat
import sys
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from compd.errors import InputFileError
from compd.files.yamlevents import build

#: Limits on any YAML file compd reads (model, config, effect catalogue): a few
#: kilobytes is typical; these bound the work a hostile or broken file can cause.
MAX_YAML_BYTES = 1 << 20
#: Values after alias expansion (``*name`` counts as everything ``&name`` holds).
MAX_YAML_NODES = 100_000
#: Nested mappings and lists (a model file needs 7).
MAX_YAML_DEPTH = 32
#: How much of a value an error message shows.
SHOWN_CHARS = 80

_Loader: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def shorten(value: object, limit: int = SHOWN_CHARS) -> str:
    """``repr(value)``, cut to ``limit`` characters: an error names a value, never echoes a file."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[: limit - 5]}...{text[-2:]}"


def read_limited(
    path: Path,
    error: type[InputFileError],
    max_bytes: int = MAX_YAML_BYTES,
    *,
    what: str = "the file",
) -> bytes:
    """The bytes of the regular file ``path``, refused beyond ``max_bytes``.

    Opened non-blocking and checked to be a regular file before reading, so
    a FIFO, a device (``/dev/zero``) or a huge file is an error, never a hang
    or an allocation the size of the input.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise error(path, f"cannot read {what} ({exc.strerror})") from exc
    with os.fdopen(fd, "rb") as file:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise error(path, "not a regular file", fix="Give the path of a YAML file")
        try:
            raw = file.read(max_bytes + 1)
        except OSError as exc:
            raise error(path, f"cannot read {what} ({exc.strerror})") from exc
    if len(raw) > max_bytes:
        raise error(
            path,
            f"larger than {max_bytes} bytes",
            fix="A model or config file is a few kilobytes; check that this is the right file",
        )
    return raw


class NodeTree:
    """A YAML text's node tree, for the line of a place: composed the first time it is asked for.

    Loading builds the document from the parser's events (:mod:`compd.files.yamlevents`);
    only an error needs lines, so only an error composes the nodes (0.4 kB a value).
    """

    __slots__ = ("_composed", "_root", "_text")

    def __init__(self, text: str, root: yaml.Node | None = None, *, composed: bool = False) -> None:
        self._text = text
        self._root = root
        self._composed = composed

    @property
    def root(self) -> yaml.Node | None:
        if not self._composed:
            loader = _Loader(self._text)
            try:
                self._root = loader.get_single_node()
            finally:
                loader.dispose()
            self._composed = True
        return self._root


def parse_yaml(text: str, path: object, error: type[InputFileError]) -> tuple[Any, NodeTree]:
    """The document and its node tree (for line numbers); a syntax error names the file and line.

    The one place compd reads YAML text, so every loader (model, config,
    effect catalogue) words a syntax error the same way, and every one is
    bounded: size, nesting and alias expansion are checked on the event
    stream (no recursion, no construction) before a node is built, and a
    duplicate key is an error rather than the last one silently winning.
    The document is built from the events where it can be (no node tree:
    :mod:`compd.files.yamlevents`), else composed and constructed.
    """
    if len(text) > MAX_YAML_BYTES:
        raise error(path, f"larger than {MAX_YAML_BYTES} bytes")
    try:
        _check_events(text, path, error)
        try:
            built, data = build(text, _Loader)
        except (ValueError, OverflowError) as exc:
            raise _unbuildable(NodeTree(text).root, exc, path, error) from exc
        if built:
            return data, NodeTree(text)
        loader = _Loader(text)
        try:
            root = loader.get_single_node()
            try:
                data = None if root is None else loader.construct_document(root)
                return data, NodeTree(text, root, composed=True)
            except (ValueError, OverflowError) as exc:
                # A scalar the YAML resolver types but Python cannot build: an integer of more
                # digits than int() converts (4300), a date such as 2024-13-45.
                raise _unbuildable(root, exc, path, error) from exc
        finally:
            loader.dispose()
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        if "nesting depth" in problem:
            # libyaml >= 0.2.6 (PyYAML 6.0.4's wheels) stops deep nesting in its scanner,
            # which reads ahead of the events walked above: the same refusal, compd's words.
            raise error(
                path,
                f"nested deeper than {MAX_YAML_DEPTH} levels",
                where=where,
                fix="Flatten the structure",
            ) from exc
        raise error(path, f"not valid YAML: {problem}", where=where) from exc


def _unbuildable(
    root: yaml.Node | None, exc: Exception, path: object, error: type[InputFileError]
) -> InputFileError:
    """The refusal of the first scalar under ``root`` that cannot be built, with its place.

    Only on the error path: each scalar is built again on its own, in document
    order, until one fails as the whole document did.
    """
    builder = _Loader("")
    try:
        stack: list[tuple[yaml.Node, tuple[str | int, ...]]] = [] if root is None else [(root, ())]
        while stack:
            node, location = stack.pop()
            if isinstance(node, yaml.MappingNode):
                children = [(v, (*location, str(k.value))) for k, v in node.value]
                stack.extend(reversed(children))
            elif isinstance(node, yaml.SequenceNode):
                stack.extend(reversed([(v, (*location, i)) for i, v in enumerate(node.value)]))
            else:
                try:
                    builder.construct_object(node, deep=True)
                except (ValueError, OverflowError) as failed:
                    huge = "digits" in str(failed)  # "Exceeds the limit (4300 digits) ..."
                    digits = sum(c.isdigit() for c in str(node.value))
                    why = (
                        f"an integer of {digits} digits (at most {sys.get_int_max_str_digits()})"
                        if huge
                        else str(failed)
                    )
                    return error(
                        path,
                        f"{shorten(node.value)} is not a value compd reads: {why}",
                        where=where(root, location),
                        fix="Give a number of a few digits" if huge else "Correct it, or quote it",
                    )
    finally:
        builder.dispose()
    return error(path, f"a value compd cannot read ({exc})")


class _Frame:
    """An open mapping or list while the event stream is walked."""

    def __init__(self, anchor: str | None, mapping: bool) -> None:
        self.anchor = anchor
        self.mapping = mapping
        self.size = 1  # this node and everything under it, aliases expanded
        self.keys: dict[str, int] = {}  # scalar key -> its line
        self.at_key = True


def _check_events(text: str, path: object, error: type[InputFileError]) -> None:
    """Refuse deep nesting, alias bombs and duplicate keys, walking the events iteratively."""
    sizes: dict[str, int] = {}  # anchor -> its expanded size
    stack: list[_Frame] = []
    total = 0
    for event in yaml.parse(text, Loader=_Loader):
        line = event.start_mark.line + 1 if event.start_mark is not None else 0
        if isinstance(event, yaml.CollectionStartEvent):
            if len(stack) >= MAX_YAML_DEPTH:
                raise error(
                    path,
                    f"nested deeper than {MAX_YAML_DEPTH} levels",
                    where=f"line {line}",
                    fix="Flatten the structure",
                )
            _key_or_value(stack, event, path, error, line)
            stack.append(_Frame(event.anchor, isinstance(event, yaml.MappingStartEvent)))
            continue
        if isinstance(event, yaml.CollectionEndEvent):
            frame = stack.pop()
            size = frame.size
            if frame.anchor is not None:
                sizes[frame.anchor] = size
        elif isinstance(event, yaml.AliasEvent):
            _key_or_value(stack, event, path, error, line)
            size = sizes.get(event.anchor or "", 1)
        elif isinstance(event, yaml.ScalarEvent):
            _key_or_value(stack, event, path, error, line)
            size = 1
            if event.anchor is not None:
                sizes[event.anchor] = 1
        else:
            continue
        if stack:
            stack[-1].size += size
        else:
            total += size
        if total + sum(f.size for f in stack) > MAX_YAML_NODES:
            raise error(
                path,
                f"holds more than {MAX_YAML_NODES} values (aliases expanded)",
                where=f"line {line}",
                fix="Write the values out, or drop the repeated aliases",
            )


def _key_or_value(
    stack: list[_Frame], event: yaml.Event, path: object, error: type[InputFileError], line: int
) -> None:
    """Track key/value alternation in the innermost mapping; a repeated scalar key is an error."""
    if not stack or not stack[-1].mapping:
        return
    frame = stack[-1]
    is_key, frame.at_key = frame.at_key, not frame.at_key
    if not is_key or not isinstance(event, yaml.ScalarEvent) or event.value == "<<":
        return
    first = frame.keys.get(event.value)
    if first is not None:
        raise error(
            path,
            f"duplicate key {shorten(event.value)} (first on line {first})",
            where=f"line {line}",
            fix="Give each key once",
        )
    frame.keys[event.value] = line


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
        message = f"{message} (got {shorten(shown)})"
    return message


def where(root: yaml.Node | NodeTree | None, location: tuple[str | int, ...]) -> str:
    """``line N (a.b[2].c)``: the dotted place, with the YAML line of the deepest node found."""
    if isinstance(root, NodeTree):
        root = root.root
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
