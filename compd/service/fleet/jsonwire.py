"""The JSON of telemetry messages: the schema name, compact encoding, numbers JSON can carry."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from importlib.metadata import PackageNotFoundError, version
from typing import Any

#: Every telemetry payload's ``schema``; a consumer checks it before reading the rest.
SCHEMA = "compd.telemetry/1"


def dumps(payload: Mapping[str, Any]) -> bytes:
    """Compact JSON; NaN and infinities are refused (use :func:`finite`)."""
    return json.dumps(payload, separators=(",", ":"), allow_nan=False, default=str).encode()


def finite(value: float) -> float | None:
    """JSON has no NaN: a missing value is ``null``; ``-0.0`` is ``0.0`` (a sign nobody measured).

    Floats are written in their shortest form that reads back the same
    (Python's ``repr``); a value's decimals are clean where the value is
    (:meth:`compd.service.loop.points.SignalPoint.convert` scales registers by
    dividing).
    """
    return value + 0.0 if math.isfinite(value) else None


def finites(values: Mapping[str, float]) -> dict[str, float | None]:
    return {k: finite(v) for k, v in values.items()}


def compd_version() -> str:
    try:
        return version("compd")
    except PackageNotFoundError:
        return "unknown"
