"""The soak's SIGHUP: the service told to reload while it runs, its config file as it was, changed or broken.

``compd run`` hands SIGHUP to :meth:`~compd.service.daemon.Service.reload`
(``loop.add_signal_handler`` in :mod:`compd.cli.daemon`); the soak runs the
service in-process and calls that method itself, with its config file on disk:

- ``unchanged``: as the service read it;
- ``changed``: valid, but changed in what only a restart applies
  (``live_every_ticks``): the reload leaves it for a restart;
- ``broken``: not YAML: the reload refuses it and runs on.

Virtual time stands still until the reload is done (it reads a config: a few
milliseconds, well within a period), then the file is put back. Judged: the
service takes every reload (:attr:`~compd.service.reload.Reloader.done`)
and never stops for one (a service that ends before the shift is a crash,
:mod:`compd.sim.soak`); the recording goes on in a new file.
"""

from __future__ import annotations

import asyncio
import time

import yaml

from compd.service.daemon import Service
from compd.sim.soakwitness import SoakResult

#: Longest (real s) the soak waits for a reload to be done before it counts it as not taken.
RELOAD_WAIT_S = 30.0


def edited(text: str, variant: str) -> str:
    """The config file's text as the ``variant`` of a ``sighup`` fault leaves it."""
    if variant == "changed":
        doc = yaml.safe_load(text)
        doc["live_every_ticks"] = int(doc.get("live_every_ticks", 600)) + 1
        return yaml.safe_dump(doc, sort_keys=False)
    if variant == "broken":
        return text + "\nperiod_s: [1.0\n"  # a flow sequence never closed
    return text


async def sighup(service: Service, variant: str, result: SoakResult) -> None:
    """SIGHUP to ``service`` with its config file edited as ``variant`` says; put back once it is done."""
    path = service.config.path
    original = path.read_bytes()
    path.write_text(edited(original.decode(), variant))
    done = service.reloader.done
    try:
        service.reload()
        deadline = time.monotonic() + RELOAD_WAIT_S
        while service.reloader.done == done and time.monotonic() < deadline:
            await asyncio.sleep(0.001)
    finally:
        path.write_bytes(original)
    if service.reloader.done > done:
        result.reloads_done += 1
    else:
        result.errors.append(f"a reload ({variant}) was not done within {RELOAD_WAIT_S:g} s")
