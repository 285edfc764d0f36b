"""``compd update``: re-optimise a model's named gains on sparse probe measurements (Post-process 2024)."""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np
from rich.table import Table

from compd.cli.common import data_options, load_data_from_args
from compd.cli.terminal import console
from compd.files.modelfile import load_model
from compd.files.provenancepaths import write_model_text
from compd.files.sidecar import copy_sidecars, residual_files
from compd.toolkit.gainsets import parse_bounds
from compd.toolkit.probes import load_probes
from compd.toolkit.summary import fmt, json_text
from compd.toolkit.update import Update, update_model


def register(commands: Any) -> None:
    update = commands.add_parser(
        "update",
        help="re-optimise the model's named gains (g1, g2, ...) on sparse probe measurements "
        "(Post-process 2024)",
        description="Post-process update (Post-process 2024, eq. 8/9): run MODEL over DATA once, then find "
        "the gains named in the model file (gain_name) that minimise the squared residue at the "
        "probe instants of PROBES, with scipy's differential evolution, within bounds (default "
        "0:2 each). The TFs are kept; only the gains change. Writes the model with the new gains "
        "and a provenance record of the probes, bounds and gains before/after.",
    )
    update.add_argument("model", type=Path, metavar="MODEL.yaml")
    update.add_argument(
        "data", type=Path, metavar="DATA.csv", help="the logged signals of the probed run"
    )
    update.add_argument(
        "--probes",
        type=Path,
        required=True,
        metavar="PROBES.csv",
        help="time_s (from DATA's first sample) and one column per probed output, e.g. "
        "disp_z_um; empty cells: not probed",
    )
    update.add_argument("--out", type=Path, required=True, metavar="NEW.yaml")
    update.add_argument(
        "--bounds",
        metavar="g1=0:2,g2=0.5:1.1",
        help="search interval per gain name (or per sub-model without one, to free its gain); "
        "named gains not listed get 0:2 (Post-process 2024, eq. 9) or their characteristic bounds",
    )
    update.add_argument(
        "--output", metavar="COLUMN", help="update only this output (default: every probed one)"
    )
    update.add_argument(
        "--characteristic-from",
        type=Path,
        metavar="CONTINUOUS.csv",
        help="a run with the displacement measured throughout: find the gains' characteristic "
        "bounds on it first (Post-process 2024, eq. 7) and search within them",
    )
    update.add_argument(
        "--segment-signal",
        default="spindle_speed_rpm",
        metavar="SIGNAL",
        help="the signal whose changes delimit the intervals of eq. 7 (default spindle_speed_rpm)",
    )
    update.add_argument(
        "--seed", type=int, default=0, help="optimiser seed: same seed, same result (default 0)"
    )
    update.add_argument("--json", action="store_true", help="print one JSON object")
    data_options(update)
    update.set_defaults(handler=_update)


def _update(args: argparse.Namespace) -> int:
    parent = load_model(args.model)
    bounds = parse_bounds(args.bounds, str(args.model))
    data = load_data_from_args(args)
    probes = load_probes(args.probes)
    continuous = (
        load_data_from_args(args, args.characteristic_from) if args.characteristic_from else None
    )
    command = (
        "compd " + shlex.join(["update", *sys.argv[2:]]) if sys.argv[1:2] == ["update"] else ""
    )
    result = update_model(
        parent,
        data,
        probes,
        bounds=bounds,
        output=args.output,
        continuous=continuous,
        segment_signal=args.segment_signal,
        seed=args.seed,
        init=args.init,
        command=command,
    )
    # The parent's residual forests stay in the new model: their sidecars go beside it.
    copy_sidecars(residual_files(parent.doc), parent.path, args.out)
    write_model_text(
        args.out, result.yaml_text, parent=parent.doc.provenance, parent_path=Path(parent.path)
    )
    summary = _summary(result, args)
    if args.json:
        print(json_text(summary))
        return 0
    _print(result, args)
    return 0


def _clean(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else math.nan


def _summary(result: Update, args: argparse.Namespace) -> dict[str, object]:
    rows = result.rows
    before = rows.measured_um - result.predicted_before_um
    after = rows.measured_um - result.predicted_after_um
    characteristic = result.characteristic
    return {
        "model": str(args.model),
        "model_sha256": result.parent.sha256,
        "out": str(args.out),
        "data": str(args.data),
        "probes": str(args.probes),
        "probe_values": int(rows.measured_um.size),
        "gains": {
            g.key: {
                "before": g.value,
                "after": float(v),
                "bounds": [float(lo), float(hi)],
                "at_bound": bool(hit),
            }
            for g, v, (lo, hi), hit in zip(
                result.gains,
                result.result.gains,
                result.bounds,
                result.result.at_bound,
                strict=True,
            )
        },
        "well_determined": result.result.well_determined,
        "probe_rms_before_um": _clean(_rms(before)),
        "probe_rms_after_um": _clean(_rms(after)),
        "probe_max_abs_before_um": _clean(float(np.max(np.abs(before)))),
        "probe_max_abs_after_um": _clean(float(np.max(np.abs(after)))),
        "fit_percent_before": {k: _clean(v) for k, v in result.fit_before.items()},
        "fit_percent_after": {k: _clean(v) for k, v in result.fit_after.items()},
        "characteristic": None
        if characteristic is None
        else {
            "data": characteristic.data.path,
            "output": characteristic.output,
            "segment_signal": characteristic.segment_signal,
            "segments": len(characteristic.result.segments),
            "bounds": {
                g.key: [float(lo), float(hi)]
                for g, (lo, hi) in zip(result.gains, characteristic.result.bounds, strict=True)
            },
            "fit_percent_before": _clean(result.characteristic_fit[0])
            if result.characteristic_fit
            else None,
            "fit_percent_after": _clean(result.characteristic_fit[1])
            if result.characteristic_fit
            else None,
            "median_segment_fit_percent": _clean(
                float(np.nanmedian(characteristic.result.segment_fit_percent))
                if np.isfinite(characteristic.result.segment_fit_percent).any()
                else math.nan
            ),
        },
        "notes": list(result.notes),
    }


def _print(result: Update, args: argparse.Namespace) -> None:
    out = console()
    characteristic = result.characteristic
    if characteristic is not None:
        table = Table(
            "gain",
            "min",
            "max",
            "characteristic bounds",
            title=f"Post-process 2024, eq. 7 on {characteristic.data.path}: best gains on "
            f"{len(characteristic.result.segments)} intervals of constant "
            f"{characteristic.segment_signal}",
        )
        for j, gain in enumerate(result.gains):
            column = characteristic.result.segment_gains[:, j]
            finite = column[np.isfinite(column)]
            low, high = characteristic.result.bounds[j]
            table.add_row(
                gain.key,
                fmt(float(finite.min()) if finite.size else None, 3),
                fmt(float(finite.max()) if finite.size else None, 3),
                f"{low:.3f} .. {high:.3f}",
            )
        out.print(table)
    table = Table(
        "gain",
        "sub-models",
        "bounds",
        "before",
        "after",
        title=f"gains of {result.parent.model.name} fitted to {result.rows.measured_um.size} probe "
        f"values in {args.probes} (Post-process 2024, eq. 8)",
    )
    model = result.parent.model
    for gain, value, (low, high), hit in zip(
        result.gains, result.result.gains, result.bounds, result.result.at_bound, strict=True
    ):
        subs = ", ".join(
            f"{model.outputs[o].name}/{model.outputs[o].submodels[s].name}" for o, s in gain.members
        )
        table.add_row(
            gain.key,
            subs,
            f"{low:g} .. {high:g}",
            f"{gain.value:.4f}",
            f"{value:.4f}" + (" (on a bound)" if hit else ""),
        )
    out.print(table)
    rows = result.rows
    before = rows.measured_um - result.predicted_before_um
    after = rows.measured_um - result.predicted_after_um
    residues = Table(
        "time (h)",
        "output",
        "measured",
        "residue before",
        "residue after",
        title="residue at the probes (um)",
    )
    for t, name, measured, b, a in zip(
        rows.time_s, rows.output, rows.measured_um, before, after, strict=True
    ):
        residues.add_row(f"{t / 3600:.2f}", name, fmt(measured), fmt(b), fmt(a))
    residues.add_row("RMS", "", "", fmt(_rms(before)), fmt(_rms(after)))
    out.print(residues)
    for name, fit_before in result.fit_before.items():
        out.print(
            f"{name}: free-run fit on {args.data} {fmt(fit_before, 1)} % before, "
            f"{fmt(result.fit_after[name], 1)} % after (the probed run itself; judge the update "
            "on a later run with compd compare)"
        )
    if characteristic is not None and result.characteristic_fit is not None:
        out.print(
            f"{characteristic.output}: free-run fit on {characteristic.data.path} (measured "
            f"continuously) {fmt(result.characteristic_fit[0], 1)} % before, "
            f"{fmt(result.characteristic_fit[1], 1)} % after"
        )
    for note in result.notes:
        out.print(f"note: {note}")
    out.print(f"wrote {args.out}")
