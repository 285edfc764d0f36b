"""A model file's discrete TFs rewritten at the daemon's loop period, as the daemon would compile them.

The bundled model is identified at 10 s and the bundled configs tick at 1 s:
the daemon resamples each TF (exact d2c then ZOH c2d, which needs scipy) when
it compiles the model. Written at 1 s, the same model compiles with numpy
alone; ``tests/test_architecture.py`` and ``benchmarks/bench_startup.py`` run
``compd run`` on it to show what the daemon loads then.

Run: ``python -m tests.loop_rate SOURCE DESTINATION PERIOD_S``.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import yaml

from compd.model.transfer import DiscreteTF, resample_discrete


def at_loop_rate(source: Path, destination: Path, period_s: float) -> Path:
    """Write ``source`` with every discrete TF resampled to ``period_s``; returns ``destination``."""
    doc: dict[str, Any] = yaml.safe_load(source.read_text())
    model_s = float(doc["sample_time_s"])
    for output in doc["outputs"].values():
        for sub in output["submodels"]:
            tf = sub["tf"]
            assert tf["form"] == "discrete" and tf.get("power_order") == "ascending", tf
            discrete = DiscreteTF.from_coefficients(tf["num"], tf["den"], tf.get("nk", 0))
            resampled = resample_discrete(discrete, model_s, period_s)
            tf["num"] = [float(v) for v in resampled.num]
            tf["den"] = [float(v) for v in resampled.den]
            tf["nk"] = int(resampled.nk)
    doc["sample_time_s"] = period_s
    destination.write_text(yaml.safe_dump(doc, sort_keys=False))
    return destination


if __name__ == "__main__":
    at_loop_rate(Path(sys.argv[1]), Path(sys.argv[2]), float(sys.argv[3]))
