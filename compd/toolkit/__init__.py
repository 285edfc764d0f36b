"""The modelling toolkit: fit, compare, diagnose, extend, update; built on the files and the numeric core.

It runs whole records (up to millions of samples, many times over in a fit)
through :func:`compd.model.run.simulate`: scipy.signal, loaded here, makes
that scipy's compiled filter loop (:mod:`compd.model.dfilter`). The daemon,
which never imports the toolkit, runs the same recursion in numpy and gets
the same numbers without scipy's ~100 MB. In a daemon-only install (no
``compd[toolkit]``, :mod:`compd.extras`) the commands that need no more than
numpy from here (``compd model updates``, ``model export --updated``) run
with numpy's loop.
"""

import contextlib

# pip install compd without [toolkit]: numpy's loop, the same numbers.
with contextlib.suppress(ModuleNotFoundError):
    import scipy.signal  # noqa: F401 - see above: the fast filter for compd.model.dfilter
