"""``compd model updates`` and ``compd model export --updated``: what the daemon's probes taught its models.

Both read the state directory (``--state-dir``, else the one of the daemon's
``--config``): the probe log and the learned states
(:mod:`compd.files.probestate`). Nothing here writes to it.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from pathlib import Path
from typing import Any

from compd.cli.args import daemon_options


def register(model: Any) -> None:
    """The ``updates`` and ``export`` actions of ``compd model``."""
    updates = model.add_parser(
        "updates",
        help="the probes the daemon took and rejected, with their innovations (the probe log)",
    )
    _state_options(updates)
    updates.add_argument(
        "--json", action="store_true", help="print the log's records as JSON, not a table"
    )
    updates.set_defaults(handler=_updates)
    export = model.add_parser(
        "export",
        help="write the model as the daemon's probes updated it, as a model file",
        description="Write MODEL with what the probes taught it (gains times the learned "
        "factors, the learned bias as the output's bias_um) to OUT, the probes named in its "
        "provenance; 'compd model load' takes it.",
    )
    export.add_argument(
        "--updated",
        action="store_true",
        required=True,
        help="the model as updated by the probes (the only export so far)",
    )
    _state_options(export)
    export.add_argument(
        "model", type=Path, metavar="MODEL.yaml", help="the model file the daemon ran"
    )
    export.add_argument("out", type=Path, metavar="OUT.yaml", help="the file to write")
    export.set_defaults(handler=_export)


def _state_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--state-dir",
        type=Path,
        metavar="DIR",
        help="the daemon's state directory (default: the one --config names)",
    )
    daemon_options(parser)


def state_dir_of(args: argparse.Namespace) -> Path:
    """``--state-dir``, else the state directory of the daemon's config."""
    if args.state_dir is not None:
        return Path(args.state_dir)
    from compd.cli.serving import config_from_arg

    return config_from_arg(args.config).state_dir


def _updates(args: argparse.Namespace) -> int:
    from compd.files.jsontext import json_text
    from compd.files.probestate import read_log

    state_dir = state_dir_of(args)
    log = read_log(state_dir)
    for problem in log.unreadable:
        print(f"note: skipped {problem}", file=sys.stderr)
    if args.json:
        print(json_text({"log": str(log.path), "probes": [r.to_dict() for r in log.records]}))
        return 0
    from rich.table import Table

    from compd.cli.terminal import console

    out = console()
    if not log.records:
        out.print(f"no probes logged in {log.path}", markup=False)
        return 0
    table = Table(
        "touched (UTC)", "model", "output", "source", "measured (um)", "predicted (um)",
        "innovation before", "after", "result",
        title=f"probes in {log.path}",
    )  # fmt: skip
    for r in log.records:
        table.add_row(
            dt.datetime.fromtimestamp(r.touched_s, dt.UTC).strftime("%Y-%m-%d %H:%M:%S"),
            r.model_sha256[:12],
            r.output + (f" ({r.axis})" if r.axis else ""),
            r.source,
            _um(r.measured_um),
            _um(r.predicted_before_um),
            _um(r.innovation_before_um, signed=True),
            _um(r.innovation_after_um, signed=True),
            r.result + (" (bounded)" if r.bounded else "") + (f": {r.reason}" if r.reason else ""),
        )
    out.print(table)
    taken = sum(r.result in ("accepted", "confirmed") for r in log.records)
    rejected = sum(r.result in ("rejected", "refused") for r in log.records)
    out.print(f"{taken} taken, {rejected} rejected or refused", markup=False)
    return 0


def _um(value: float | None, *, signed: bool = False) -> str:
    if value is None:
        return "-"
    return f"{value:+.2f}" if signed else f"{value:.2f}"


def _export(args: argparse.Namespace) -> int:
    from compd.cli.terminal import console
    from compd.files.modelfile import load_model
    from compd.files.provenancepaths import with_portable_provenance
    from compd.files.sidecar import copy_sidecars, residual_files
    from compd.files.unreadable import write_atomic
    from compd.toolkit.probeexport import export_updated

    model_file = load_model(args.model)
    exported = export_updated(
        model_file, state_dir_of(args), command=" ".join(["compd", *sys.argv[1:]])
    )
    out_path = Path(args.out)
    copy_sidecars(residual_files(model_file.doc), model_file.path, out_path)
    # The parent's recorded paths are relative to its folder: seen from the new file's.
    text = with_portable_provenance(
        exported.text,
        out_path,
        parent=model_file.doc.provenance,
        parent_path=Path(model_file.path),
    )
    write_atomic(out_path, text.encode())
    for note in exported.notes:
        print(f"note: {note}", file=sys.stderr)
    out = console()
    for name, learner in exported.learned.items():
        # Each sub-model's gain is multiplied by its learned coefficient over the file's.
        multipliers = learner.theta[:-1] / learner.prior.units[:-1]
        factors = ", ".join(
            f"{n} x{v:.3f}" for n, v in zip(learner.prior.names[:-1], multipliers, strict=True)
        )
        out.print(f"{name}: gains {factors}; bias {learner.theta[-1]:+.3f} um", markup=False)
    out.print(
        f"wrote {out_path} (sha256 {exported.updated.sha256[:12]}): "
        f"{len({(p.output, p.touched_s) for p in exported.probes})} probes since the last reset, "
        f"parent {model_file.sha256[:12]}; "
        f"check it with 'compd model check {out_path}'",
        markup=False,
    )
    return 0
