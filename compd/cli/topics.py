"""The pages of ``compd help``, the man page and the completion scripts, generated from compd itself.

Nothing here is written twice: the config and model-file pages walk the
pydantic schemas the files are validated against (key, type, bounds,
default); the status-word page reads the safety stage's bit constants; the
man page and the completion scripts are generated from the full parser
(:func:`compd.cli.build_parser`) by argparse-manpage and shtab.
"""

from __future__ import annotations

import argparse
import re
import textwrap
import types
import typing
from pathlib import Path

from pydantic import BaseModel

from compd import __version__
from compd.cli import COMMANDS, VERSION, build_parser
from compd.cli.args import EXIT_INPUT_ERROR, EXIT_NOT_CONNECTED
from compd.cli.references import references_page
from compd.cli.topicnames import TOPICS
from compd.errors import CompdError

#: Unit suffixes of signal and column names (``compd.toolkit.fitmodel.unit_of`` reads them).
UNIT_SUFFIXES = {
    "_degC": "temperature, degrees Celsius (T_spindle_degC)",
    "_K": "temperature difference, kelvin",
    "_rpm": "spindle speed, revolutions per minute (spindle_speed_rpm)",
    "_kw": "power, kilowatts (spindle_power_kw); _kW and _W are read too",
    "_um": "displacement or offset, micrometres (disp_z_um); every offset compd writes is in um",
    "_mm": "axis position, millimetres (X_position_mm)",
    "_s": "time or duration, seconds (time_s, period_s)",
    "_bar": "pressure, bar",
    "_percent": "a share in percent (_pct is read too)",
}
#: Suffixes of the naming convention that ``unit_of`` does not read (their unit is "-" in a fit).
NAMED_ONLY = {"_mm_per_min": "feed rate, millimetres per minute (feed_x_mm_per_min)"}


def help_text(topic: str | None, *, man: bool = False) -> str:
    """The page ``compd help [TOPIC]`` prints (``man``: the roff manual page)."""
    if man:
        return man_page()
    if topic is None:
        return _index()
    if topic in COMMANDS:
        parser = build_parser(COMMANDS[topic][0])
        return _subparser(parser, topic).format_help()
    pages = {
        "config": config_page,
        "model-file": model_file_page,
        "units": units_page,
        "status-word": status_word_page,
        "exit-codes": exit_codes_page,
        "references": references_page,
    }
    if topic not in pages:
        raise CompdError(
            f"no command or help topic {topic!r}: give a command ({', '.join(COMMANDS)}) "
            f"or a topic ({', '.join(TOPICS)}), or run 'compd help' for the list"
        )
    return pages[topic]()


def _index() -> str:
    width = max(map(len, [*COMMANDS, *TOPICS])) + 2
    lines = [VERSION.splitlines()[0], "", "Commands (compd help COMMAND: its full help):"]
    lines += [f"  {name:<{width}}{text.replace('%%', '%')}" for name, (_, text) in COMMANDS.items()]
    lines += ["", "Topics (compd help TOPIC):"]
    lines += [f"  {name:<{width}}{text}" for name, text in TOPICS.items()]
    lines += ["", "The manual page: man compd (installed by pip), or compd help --man | man -l -"]
    return "\n".join(lines)


def _subparser(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    for action in parser._actions:  # argparse keeps its sub-parsers only here
        if isinstance(action, argparse._SubParsersAction):
            return action.choices[name]  # type: ignore[no-any-return]
    raise LookupError(name)


# --- schema pages -------------------------------------------------------------


def config_page() -> str:
    from compd.files.yamlplace import resolve_path
    from compd.service.config.docs import SCHEMA, ConfigDoc

    example = resolve_path("bundled:compd.example.yaml", Path("."))
    head = [
        f"The daemon config (schema {SCHEMA}): a YAML file, checked by `compd check-config FILE` "
        "exactly as `compd run` checks it. Unknown keys are errors.",
        f"Every key, commented, in the annotated example: bundled:compd.example.yaml ({example}).",
        "",
        "key: type (= default); required keys have no default",
    ]
    return "\n".join([*head, *schema_tree(ConfigDoc)])


def model_file_page() -> str:
    from compd.files.modelschema import SCHEMA, ModelDoc

    head = [
        f"The model file (schema {SCHEMA}): a YAML file, checked by `compd model check FILE`. "
        "Written by `compd fit`, `extend`, `update`, `residual`; unknown keys are errors.",
        "Paths in provenance are relative to the model file's folder (or bundled:NAME).",
        "",
        "key: type (= default); required keys have no default",
    ]
    return "\n".join([*head, *schema_tree(ModelDoc)])


def schema_tree(doc: type[BaseModel], indent: int = 0) -> list[str]:
    """One line per key of ``doc`` (a pydantic model): ``key: type (= default)``, sections nested.

    A field's ``description`` follows as a comment (what it is, in which
    unit); ``json_schema_extra={"default_is": TEXT}`` shows a key the
    document fills in from another (so it is not shown as required).
    """
    lines: list[str] = []
    hints = typing.get_type_hints(doc, include_extras=True)
    for name, field in doc.model_fields.items():
        key = field.alias or name
        annotation = hints.get(name, field.annotation)
        text = f"{'  ' * (indent + 1)}{key}: {_type_name(annotation)}"
        extra = field.json_schema_extra if isinstance(field.json_schema_extra, dict) else {}
        if "default_is" in extra:  # filled in by the document from another key
            text += f" (= {extra['default_is']})"
        elif not field.is_required():
            default = field.get_default(call_default_factory=True)
            if isinstance(default, BaseModel):
                text += " (= {...})"
            elif default not in ({}, [], (), None):
                text += f" (= {default!r})"
        text += _bounds(field.metadata)
        lines += _described(text, field.description, indent + 2)
        for section in _sections(annotation):
            if section.__doc__ and section.__doc__ != BaseModel.__doc__:
                summary = plain(section.__doc__.strip().splitlines()[0])
                lines.append(f"{'  ' * (indent + 2)}# {summary}")
            lines += schema_tree(section, indent + 1)
    return lines


#: The widest line a key and its description share; a longer description is wrapped beneath.
_WIDTH = 100


def _described(text: str, description: str | None, indent: int) -> list[str]:
    """``text`` with ``description`` as a comment: on its line where it fits, else wrapped beneath."""
    if not description:
        return [text]
    comment = plain(description)
    if len(text) + len(comment) + 4 <= _WIDTH:
        return [f"{text}  # {comment}"]
    pad = "  " * indent + "# "
    return [text, *textwrap.wrap(comment, _WIDTH, initial_indent=pad, subsequent_indent=pad)]


#: reStructuredText roles (``:mod:`x```, ``:class:`~a.B```) and literals (````x````), for :func:`plain`.
_ROLE = re.compile(r":[a-z]+:`~?([^`]+)`")
_LITERAL = re.compile(r"``([^`]+)``")


def plain(text: str) -> str:
    """A docstring line as a terminal shows it: ``:mod:`a.b``` -> a.b, ````x```` -> 'x'."""
    text = _ROLE.sub(lambda m: m[1], text)
    return _LITERAL.sub(lambda m: f"'{m[1]}'", text)


def _sections(annotation: object) -> list[type[BaseModel]]:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    found: list[type[BaseModel]] = []
    for arg in typing.get_args(annotation):
        found += [s for s in _sections(arg) if s not in found]
    return found


def _type_name(annotation: object) -> str:
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        return _type_name(args[0]) + _bounds(args[1:])
    if origin is typing.Literal:
        return " | ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_name(a) for a in args)
    if origin is not None:
        inner = ", ".join("..." if a is Ellipsis else _type_name(a) for a in args)
        return f"{getattr(origin, '__name__', str(origin))}[{inner}]"
    if annotation is type(None):
        return "null"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "section"
    return getattr(annotation, "__name__", str(annotation))


def _bounds(metadata: typing.Iterable[object]) -> str:
    """Bounds from pydantic/annotated-types metadata (``Gt(gt=0)`` -> ``> 0``)."""
    signs = {"gt": ">", "ge": ">=", "lt": "<", "le": "<=", "min_length": "length >=",
             "max_length": "length <="}  # fmt: skip
    found = []
    for item in metadata:
        for attribute, sign in signs.items():
            value = getattr(item, attribute, None)
            if value is not None and not callable(value):
                found.append(f"{sign} {value}")
    return f" [{', '.join(found)}]" if found else ""


# --- fixed pages ---------------------------------------------------------------


def units_page() -> str:
    lines = [
        "compd's names carry their units: a signal or column name ends in its unit, so a file "
        "read by a person or a program says what it holds.",
        "`compd fit` takes each input's unit from its name; a name without one gets unit '-'.",
        "",
    ]
    width = max(map(len, [*UNIT_SUFFIXES, *NAMED_ONLY])) + 2
    lines += [f"  {suffix:<{width}}{text}" for suffix, text in UNIT_SUFFIXES.items()]
    lines += [f"  {suffix:<{width}}{text}; `compd fit` records its unit as '-'"
              for suffix, text in NAMED_ONLY.items()]  # fmt: skip
    lines += [
        "",
        "Config keys follow the same rule: period_s, max_offset_um, max_rate_um_per_s, "
        "reference_mm.",
        "Time: a data file's first column is time_s (seconds) or a timestamp "
        "(time, timestamp, datetime).",
    ]
    return "\n".join(lines)


def status_word_page() -> str:
    from compd.service.loop.safety import HEARTBEAT_MODULO, SIGNAL_BIT0, STATUS_BITS, Flag, Level

    lines = [
        f"The status word ({STATUS_BITS} bits) compd writes to the PLC beside the offsets, "
        "every tick (compd.service.loop.safety):",
        "",
        "  bits 0-1  level: " + ", ".join(f"{level.value} {level.name.lower()}" for level in Level),
    ]
    for flag in Flag:
        bit = flag.value.bit_length() - 1
        lines.append(f"  bit {bit:<5} {flag.name.lower().replace('_', ' ')}")
    lines += [
        f"  bits {SIGNAL_BIT0}-{STATUS_BITS - 1} one per configured signal, in config order "
        "(bit 8 the first), set while it is not OK",
        f"  bit {SIGNAL_BIT0}+n    offset readback mismatch (n signals): an offset point did not "
        "hold what compd wrote",
        f"  bit {SIGNAL_BIT0}+n+1  model fault: the model's output is not finite, a model "
        "failed and was unloaded, or an axis's target sat at the clamp or beyond its "
        "calibration for safety.envelope_after_s",
        "",
        "Where the status register has no bit left (a 16-bit register, many signals), the "
        "mismatch and model-fault bits are only logged and counted.",
        f"The heartbeat counts ticks modulo {HEARTBEAT_MODULO} (a PLC INT): when it stops "
        "changing, compd is gone and the PLC falls back on its own.",
    ]
    return "\n".join(lines)


def exit_codes_page() -> str:
    return "\n".join(
        [
            "compd's exit status:",
            "",
            "  0  done (for `compd run`: stopped on request, or --duration-s elapsed)",
            f"  {EXIT_INPUT_ERROR}  refused: a bad option, file, config or model (the message "
            "names the file, the place and the fix), or no daemon for `compd status`",
            "  1  an unexpected failure (a traceback follows: please report it); for `compd read`",
            "     and `compd probe`: a point could not be read or failed its checks",
            f"  {EXIT_NOT_CONNECTED}  `compd run --duration-s` ended with a driver that never answered "
            "(nothing was read from or written to the machine)",
            "",
            "Any error in a config or model aborts before the first write to a machine.",
        ]
    )


# --- generated from the parser -------------------------------------------------


def man_page() -> str:
    """``compd.1`` in roff: every command's options (argparse-manpage), then the topic pages."""
    from argparse_manpage.manpage import Manpage

    parser = build_parser()
    page = Manpage(
        parser,
        _data={
            "project_name": "compd",
            "version": __version__,
            "manual_title": "compd manual",
            "description": "thermal-error compensation for CNC machine tools",
        },
    )
    sections = [
        ("EXIT STATUS", exit_codes_page()),
        ("STATUS WORD", status_word_page()),
        ("UNITS", units_page()),
        ("SEE ALSO", "compd help TOPIC for the config and model-file keys; README.md and docs/"),
    ]
    text = str(page).replace("%%", "%").rstrip("\n") + "\n"  # argparse escapes, unexpanded
    text = escape_quote_lines(text)
    for title, body in sections:
        text += f".SH {_roff_quote(title)}\n.nf\n{_roff_text(body)}\n.fi\n"
    return text


def escape_quote_lines(roff: str) -> str:
    """Roff with no text line read as a control line: a help line wrapped to start with ``'``.

    argparse-manpage writes its macros with ``.``, never ``'``, but wraps help
    text wherever the width falls: a line such as ``'experiment' column ...``
    would be read as the undefined macro ``experiment'`` and its text lost.
    """
    return "\n".join("\\&" + line if line.startswith("'") else line for line in roff.split("\n"))


def _roff_quote(text: str) -> str:
    return '"' + text.replace('"', '""') + '"'


def _roff_text(text: str) -> str:
    """Literal lines for ``.nf``: backslashes escaped, no line starting with a control character."""
    lines = text.replace("\\", "\\e").splitlines()
    return "\n".join("\\&" + line if line[:1] in (".", "'") else line for line in lines)


def completion_script(shell: str) -> str:
    """shtab's completion script of the full parser; path arguments complete file names."""
    import shtab

    parser = build_parser()
    _mark_paths(parser)
    return str(shtab.complete(parser, shell=shell))


def _mark_paths(parser: argparse.ArgumentParser) -> None:
    """Options that take a file (a ``Path`` type or a FILE-like metavar) complete file names.

    An option with ``completion_choices`` completes those (the completion's parser only).
    """
    import shtab

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _mark_paths(sub)
            continue
        offered = getattr(action, "completion_choices", None)
        if offered is not None:  # values the command checks itself, completed as choices
            action.choices = offered
            continue
        metavar = str(action.metavar or "")
        if action.type is Path or any(
            word in metavar.upper() for word in ("FILE", ".YAML", ".CSV", "DIR", "PATH")
        ):
            action.complete = shtab.FILE  # type: ignore[attr-defined]
