"""compd's optional extras: the modules each brings, and the line that installs it.

``pip install compd`` is the daemon, its Modbus, serial, CAN and LinuxCNC
drivers and the command line for operations: what an edge PC that only
compensates needs (numpy steps the models). Extras add, by name:

- ``toolkit``: the modelling toolkit's libraries (scipy, pandas, plotly,
  scikit-learn, threadpoolctl, EMD-signal) for ``fit``, ``compare``,
  ``diagnose``, ``extend``, ``report``, the twin and the simulated machine;
  it includes ``opcua`` (the twin serves OPC UA controllers too);
- ``opcua``: asyncua, for the OPC UA driver (SINUMERIK, HEIDENHAIN, TwinCAT
  or CODESYS over OPC UA).

A command that reaches for an extra's module without it ends with
:func:`hint`'s one line and exit status 2, not a traceback; a driver type
that cannot be imported for that reason says which extra to install.
``pyproject.toml``'s ``[project.optional-dependencies]`` lists the
distributions; ``tests/test_extras.py`` checks that :data:`EXTRAS` names their
import names.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Extra:
    """One optional extra: what it is, in a sentence's words, and its distributions' top-level modules."""

    what: str
    modules: frozenset[str]


#: Each extra by its name in ``pip install 'compd[NAME]'``.
EXTRAS: dict[str, Extra] = {
    "toolkit": Extra(
        "the modelling toolkit",
        frozenset({"scipy", "pandas", "plotly", "sklearn", "threadpoolctl", "PyEMD"}),
    ),
    "opcua": Extra("the OPC UA driver's library", frozenset({"asyncua"})),
}


@dataclass(frozen=True)
class Missing:
    """A module an extra brings, not installed."""

    extra: str
    module: str

    @property
    def install(self) -> str:
        return f"pip install 'compd[{self.extra}]'"


def missing_extra(exc: BaseException | None) -> Missing | None:
    """The extra whose absent module raised ``exc``, or None for any other error.

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
            for name, extra in EXTRAS.items():
                if top in extra.modules:
                    return Missing(name, top)
        if isinstance(current, BaseExceptionGroup):
            pending.extend(current.exceptions)
        pending.append(current.__cause__)
    return None


def hint(command: str, missing: Missing) -> str:
    """The one line a command prints that needs an extra not installed."""
    what = EXTRAS[missing.extra].what
    return f"{command} needs {what}: {missing.install} ({missing.module} is not installed)"
