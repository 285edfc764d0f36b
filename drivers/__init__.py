"""Protocol drivers (Modbus TCP/RTU, OPC UA, CAN gateway, serial), installed as ``compd.drivers``.

This folder is the repository's top-level ``drivers/``, mapped to
``compd.drivers`` by pyproject.toml's ``package-dir`` alone, so that no
top-level ``drivers`` package lands in site-packages: a wheel copies it to
``compd/drivers/``; an editable install maps it in its import finder. There
is no link in the checkout, so a checkout that is imported without being
installed would take ``compd`` from itself and ``compd.drivers`` (and the
bundled configs) from whichever checkout is installed: refused here, with
the fix.

``base`` is the interface, ``registry`` finds a type by name; one module per
protocol, or a sub-package where a protocol has several (``modbus``,
``opcua``, ``gateway``). This file imports none of them.
"""

from pathlib import Path as _Path

import compd as _compd

_here = _Path(__file__).resolve().parent
_package = _Path(_compd.__file__).resolve().parent
# A wheel: compd/drivers/. An editable install: drivers/ beside compd/ in one checkout.
if _here not in (_package / "drivers", _package.parent / "drivers"):
    raise ImportError(
        f"compd comes from {_package} but compd.drivers from {_here}: another checkout is "
        f"installed. Install this one (pip install -e {_package.parent}) in a virtual "
        "environment, or run from the installed checkout"
    )
