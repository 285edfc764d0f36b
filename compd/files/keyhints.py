"""The keys a pydantic model accepts at a place, and the nearest to a misspelt one.

For an unknown key (pydantic's ``extra_forbidden``), the fix names the key
meant (``difflib``) and the keys allowed there, so a user need not open the
example config to find that ``max_rate_um_per_sec`` is ``max_rate_um_per_s``.
"""

from __future__ import annotations

import types
import typing
from collections.abc import Mapping, Sequence
from typing import Any

from pydantic import BaseModel


def known_keys(model: Any, loc: Sequence[str | int]) -> list[str] | None:
    """The keys the model accepts in the mapping at ``loc`` (pydantic's location); None: not a model there."""
    current: Any = model
    for part in loc:
        current = _step(current, part)
        if current is None:
            return None
    model_class = _model(current)
    if model_class is None:
        return None
    return [field.alias or name for name, field in model_class.model_fields.items()]


def unknown_key_hint(model: Any, loc: Sequence[str | int]) -> str:
    """``did you mean 'x'?; keys here: a, b, c`` for the unknown key at ``loc``; '' when not known."""
    import difflib  # only on an error's way out: a daemon that starts never loads it

    keys = known_keys(model, loc[:-1])
    if not keys:
        return ""
    close = difflib.get_close_matches(str(loc[-1]), keys, n=1, cutoff=0.6)
    meant = f"did you mean {close[0]!r}? " if close else ""
    return f"{meant}keys here: {', '.join(keys)}"


def _model(annotation: Any) -> type[BaseModel] | None:
    """The BaseModel an annotation names, through Optional and unions (the first model)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in _union_args(annotation):
        if (found := _model(arg)) is not None:
            return found
    return None


def _union_args(annotation: Any) -> tuple[Any, ...]:
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType) or origin is typing.Annotated:
        return typing.get_args(annotation)
    return ()


def _step(annotation: Any, part: str | int) -> Any:
    """The annotation one step into ``annotation`` (a field, a mapping's value, a list item)."""
    model_class = _model(annotation)
    if model_class is not None:
        field = model_class.model_fields.get(str(part))
        if field is None:
            field = next((f for f in model_class.model_fields.values() if f.alias == part), None)
        return None if field is None else field.annotation
    for candidate in (annotation, *_union_args(annotation)):
        origin = typing.get_origin(candidate)
        args = typing.get_args(candidate)
        if origin in (dict, Mapping):
            return args[1] if len(args) == 2 else None
        if origin in (list, tuple, Sequence) and args:
            return args[0]
    return None
