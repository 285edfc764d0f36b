"""What every config section's document shares: strict and frozen, numbers that are finite and bounded.

A number that is finite can still break what uses it: ``max_offset_um:
1e308`` times an encoding's scale is infinite (and ``round`` of it an
OverflowError), ``keepalive_s: 10**40`` no timer takes. So every number in
every section (nested lists and mappings included, a driver's settings too)
is bounded in magnitude: by :data:`MAX_SECONDS` where its key ends in ``_s``
(compd's names carry their units: a duration), else by :data:`MAX_NUMBER`;
both far beyond any machine's, well inside what floats, timers
(``threading.TIMEOUT_MAX``, about 9.2e9 s) and 64-bit integers carry. A key
with a tighter bound of its own (a port, MQTT's keep-alive) says so in its field.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

#: The largest magnitude of a number in a config (a byte count of 1 PB, 1e15 um): beyond it
#: arithmetic on the value overflows or means nothing on a machine.
MAX_NUMBER = 1e15
#: The longest duration in a config (a key ending in ``_s``): 1e9 s, 31 years; timers take no
#: more than ``threading.TIMEOUT_MAX`` (about 9.2e9 s) and raise OverflowError beyond.
MAX_SECONDS = 1e9

FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class Strict(BaseModel):
    """A config section: unknown keys are errors (a misspelt key must not pass silently).

    Every number in it, however deep, is within ``±``:data:`MAX_NUMBER`.
    """

    # Patterns matched by Python's re (written with \Z, which ends a value as Rust's $ does):
    # each Rust regex pydantic compiles costs the daemon 0.1-0.3 MB. Schemas built when first
    # used: a section's own validator only where it is validated alone.
    model_config = ConfigDict(
        extra="forbid", frozen=True, regex_engine="python-re", defer_build=True
    )

    @field_validator("*", mode="after")
    @classmethod
    def _bounded(cls, value: Any, info: ValidationInfo) -> Any:
        if (found := _beyond(value, info.field_name or "")) is not None:
            number, name, bound = found
            what = "duration" if bound == MAX_SECONDS else "number"
            raise ValueError(
                f"{_short(number)}{f' ({name})' if name != info.field_name else ''} is beyond "
                f"the largest {what} a config takes ({bound:.0e} either way): "
                "give a value a machine can have"
            )
        return value


def _beyond(value: Any, name: str) -> tuple[float | int, str, float] | None:
    """The first number in ``value`` beyond its bound, with its key and the bound; lists and mappings searched.

    ``name``: the key ``value`` stands under (a mapping's keys name what they hold).
    """
    if isinstance(value, bool):
        return None
    if isinstance(value, int | float):
        bound = MAX_SECONDS if name.endswith("_s") else MAX_NUMBER
        return (value, name, bound) if abs(value) > bound else None
    items: list[tuple[str, Any]] = []
    if isinstance(value, dict):
        items = [(str(k), v) for k, v in value.items()]
    elif isinstance(value, list | tuple | set | frozenset):
        items = [(name, v) for v in value]
    for key, item in items:
        if (found := _beyond(item, key)) is not None:
            return found
    return None


def _short(number: float | int) -> str:
    """A number as a person wrote it, shortened: 10**40 as 1e+40, not 41 digits."""
    return f"{number:.6g}" if isinstance(number, float) or abs(number) >= 10**15 else str(number)
