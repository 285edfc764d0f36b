"""The catalogue of physical effects: which thermal effect a logged signal stands for.

``compd diagnose`` finds the signal that explains a model's residue; a user
needs the physical effect behind it ("cutting process heat", not
``spindle_power_kw``) to decide what sub-model to add. The mapping is data,
not code: ``config/effects.yaml`` (bundled, installed as ``compd.bundled``)
holds glob patterns -> effect text, first match wins, and a user file given
with ``--catalogue`` is tried first, so site-specific column names and
effects take precedence over the bundled ones. Matching is case-insensitive
(``fnmatch`` rules: ``*``, ``?``, ``[abc]``).

Schema ``compd.effects/1``::

    schema: compd.effects/1
    effects:
      - match: ["spindle_power*"]      # one pattern or a list
        effect: cutting process heat

Unknown keys and empty patterns are errors naming the file, the line and the fix.
"""

from __future__ import annotations

from dataclasses import dataclass
from fnmatch import fnmatchcase
from importlib import resources
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from compd.errors import InputFileError
from compd.files.yamlplace import FIXES, describe, parse_yaml, read_limited, where

SCHEMA = "compd.effects/1"
BUNDLED_NAME = "effects.yaml"
UNKNOWN_EFFECT = "unknown effect"


class _EntryDoc(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    match: list[str] = Field(min_length=1)
    effect: str = Field(min_length=1)

    @field_validator("match", mode="before")
    @classmethod
    def _one_or_many(cls, value: object) -> object:
        return [value] if isinstance(value, str) else value

    @field_validator("match")
    @classmethod
    def _not_blank(cls, patterns: list[str]) -> list[str]:
        if any(not p.strip() for p in patterns):
            raise ValueError("a pattern is empty; give a column name or a glob such as 'feed_*'")
        return patterns


class _CatalogueDoc(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    schema_: Literal["compd.effects/1"] = Field(alias="schema")
    effects: list[_EntryDoc] = Field(min_length=1)


@dataclass(frozen=True)
class EffectEntry:
    """Glob patterns and the effect they stand for; ``source`` is the file it came from."""

    patterns: tuple[str, ...]
    effect: str
    source: str

    def matches(self, signal: str) -> bool:
        name = signal.lower()
        return any(fnmatchcase(name, p.lower()) for p in self.patterns)


@dataclass(frozen=True)
class EffectCatalogue:
    """Entries in precedence order: user entries first, then the bundled ones."""

    entries: tuple[EffectEntry, ...]

    def entry_for(self, signal: str) -> EffectEntry | None:
        """The first entry whose patterns match ``signal``, or ``None``."""
        return next((e for e in self.entries if e.matches(signal)), None)

    def effect_for(self, signal: str) -> str:
        """The physical effect ``signal`` stands for; ``"unknown effect"`` when nothing matches."""
        entry = self.entry_for(signal)
        return UNKNOWN_EFFECT if entry is None else entry.effect


def load_catalogue(extra: Path | None = None) -> EffectCatalogue:
    """The bundled catalogue, preceded by the entries of ``extra`` (a user file) if given."""
    bundled = resources.files("compd.bundled") / BUNDLED_NAME
    entries = parse_catalogue(bundled.read_text(encoding="utf-8"), f"bundled:{BUNDLED_NAME}")
    if extra is not None:
        path = Path(extra)
        text = read_limited(path, InputFileError, what="the effect catalogue").decode(
            "utf-8", errors="replace"
        )
        entries = parse_catalogue(text, path) + entries
    return EffectCatalogue(entries)


def parse_catalogue(text: str, path: str | Path = "<catalogue>") -> tuple[EffectEntry, ...]:
    """Validate catalogue text (schema ``compd.effects/1``); ``path`` is only used in messages."""
    data, root = parse_yaml(text, path, InputFileError)
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise InputFileError(
            path,
            "not an effect catalogue",
            where="schema",
            fix=f"Start the file with 'schema: {SCHEMA}' and list entries under 'effects:' "
            "(see config/effects.yaml)",
        )
    try:
        doc = _CatalogueDoc.model_validate(data)
    except ValidationError as exc:
        errors = sorted(exc.errors(), key=lambda e: e["type"] != "extra_forbidden")
        error = errors[0]
        raise InputFileError(
            path,
            describe(error),
            where=where(root, tuple(error["loc"])),
            fix=FIXES.get(error["type"], "See config/effects.yaml for the schema"),
        ) from exc
    return tuple(EffectEntry(tuple(e.match), e.effect, str(path)) for e in doc.effects)
