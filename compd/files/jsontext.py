"""The text every ``--json`` option prints: strict JSON, non-finite numbers null.

Below the toolkit, so that the operations commands (``compd model updates``)
print the same JSON in a daemon-only install, without pandas or scipy.
"""

from __future__ import annotations

import json
import math


def json_clean(value: object) -> object:
    """NaN and +-inf become ``null`` (JSON has neither; scripts read undefined values as null).

    Infinite figures come from data near the float range (values of 1e300
    overflow in a model's output): the figure is undefined, not an error.
    """
    return None if isinstance(value, float) and not math.isfinite(value) else value


def json_finite(value: object) -> object:
    """``value`` with :func:`json_clean` applied to every float at any depth of dicts and lists."""
    if isinstance(value, dict):
        return {k: json_finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_finite(v) for v in value]
    return json_clean(value)


def json_text(value: object) -> str:
    """The text every ``--json`` option prints: indented, strict JSON, non-finite numbers null."""
    return json.dumps(json_finite(value), indent=2, allow_nan=False)
