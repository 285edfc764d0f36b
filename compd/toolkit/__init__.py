"""The modelling toolkit: fit, compare, diagnose, extend, update; built on the files and the numeric core.

It runs whole records (up to millions of samples, many times over in a fit)
through :func:`compd.model.run.simulate`: scipy.signal, loaded here, makes
that scipy's compiled filter loop (:mod:`compd.model.dfilter`). The daemon,
which never imports the toolkit, runs the same recursion in numpy and gets
the same numbers without scipy's ~100 MB.
"""

import scipy.signal  # noqa: F401 - see above: the fast filter for compd.model.dfilter
