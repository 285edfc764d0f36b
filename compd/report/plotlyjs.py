"""The plotly.js the report inlines: the basic partial bundle, 1.2 MB instead of 4.8 MB.

The report draws only ``scatter`` and ``bar`` traces, both in plotly.js's
*basic* partial bundle (``scatter``, ``bar``, ``pie``; npm
``plotly.js-basic-dist-min``, MIT, shipped beside this module with its
licence). It is inlined, so the page still opens offline. The figures are
serialised by the installed plotly package for the plotly.js it bundles: the
partial bundle is used only when its major version is that one's, otherwise
the full bundle (a larger file, the same page). To refresh it with plotly:
``npm pack plotly.js-basic-dist-min@VERSION`` and copy
``package/plotly-basic.min.js`` and ``package/LICENSE`` here.
"""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

from plotly.offline import get_plotlyjs, get_plotlyjs_version

BASIC_BUNDLE = Path(__file__).with_name("plotly-basic.min.js")
#: The trace types the basic bundle draws; the report must use no other.
BASIC_TRACES = frozenset({"scatter", "bar", "pie"})


def basic_version() -> str:
    """The shipped basic bundle's plotly.js version (from its header comment)."""
    head = BASIC_BUNDLE.read_text(encoding="utf-8")[:300]
    found = re.search(r"plotly\.js \(basic - minified\) v(\d+\.\d+\.\d+)", head)
    if found is None:
        raise ValueError(f"{BASIC_BUNDLE}: no plotly.js version in its header")
    return found.group(1)


@cache
def plotly_js() -> str:
    """The plotly.js source to inline: the basic bundle if it matches plotly's, else the full one."""
    if BASIC_BUNDLE.exists() and _major(basic_version()) == _major(get_plotlyjs_version()):
        return BASIC_BUNDLE.read_text(encoding="utf-8")
    full: str = get_plotlyjs()
    return full


def _major(version: str) -> str:
    return version.split(".", 1)[0]
