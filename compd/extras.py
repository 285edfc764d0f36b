"""compd's optional extras: the modules each brings, and the line that installs it.

``pip install compd`` is the daemon, its drivers and the command line for
operations: what an edge PC that only compensates needs (numpy steps the
models). ``pip install 'compd[toolkit]'`` adds the modelling toolkit's
libraries: scipy, pandas, plotly, scikit-learn, threadpoolctl and EMD-signal,
for ``fit``, ``compare``, ``diagnose``, ``extend``, ``report``, the twin and
the simulated machine. A command that reaches for one of them without it ends
with :func:`toolkit_hint`'s one line and exit status 2, not a traceback.

``pyproject.toml``'s ``toolkit`` extra lists the distributions;
``tests/test_extras.py`` checks that :data:`TOOLKIT_MODULES` are their import names.
"""

from __future__ import annotations

#: The top-level import names of the toolkit extra's distributions.
TOOLKIT_MODULES = frozenset({"scipy", "pandas", "plotly", "sklearn", "threadpoolctl", "PyEMD"})

#: What installs the toolkit beside an installed compd.
TOOLKIT_INSTALL = "pip install 'compd[toolkit]'"


def missing_toolkit_module(exc: BaseException | None) -> str | None:
    """The toolkit module whose absence raised ``exc``, or None for any other error.

    ``exc`` itself, what it was raised from (``raise ... from``) or, for an
    exception group, any of its members: a command's import may be wrapped on
    its way out (a driver that cannot be imported, a task group).
    """
    seen: set[int] = set()
    pending = [exc]
    while pending:
        current = pending.pop()
        if current is None or id(current) in seen:
            continue
        seen.add(id(current))
        if isinstance(current, ModuleNotFoundError) and current.name:
            top = current.name.partition(".")[0]
            if top in TOOLKIT_MODULES:
                return top
        if isinstance(current, BaseExceptionGroup):
            pending.extend(current.exceptions)
        pending.append(current.__cause__)
    return None


def toolkit_hint(command: str, module: str) -> str:
    """The one line a command that needs the toolkit prints without it."""
    return f"{command} needs the modelling toolkit: {TOOLKIT_INSTALL} ({module} is not installed)"
