"""``compd model compile``: a model file's difference equations at the loop periods, written into it.

The daemon steps the equations a model file carries and converts nothing
(:mod:`compd.model.precompiled`); this derives them (zero-order hold, exact
resampling: scipy) for each period asked and each the file already carries,
and rewrites only the file's ``difference_equations`` section
(:func:`compd.files.equations.with_equations`), comments and everything
else as written. The result is read back before it replaces anything, so a
file is never left that compd would refuse.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from compd.errors import ModelError, ModelFileError
from compd.files.equations import MAX_PERIODS, with_equations
from compd.files.modelfile import ModelFile, model_source, parse_model, parse_model_bytes
from compd.files.modelwriter import equations_lines
from compd.files.provenancepaths import with_portable_provenance
from compd.files.sidecar import copy_sidecars, residual_files
from compd.files.unreadable import write_atomic
from compd.files.yamlplace import parse_yaml, read_limited
from compd.model.precompiled import (
    DifferenceEquations,
    derive,
    model_needs_conversion,
    same_period,
    tfs_sha256,
)


@dataclass(frozen=True)
class Compiled:
    """What ``compd model compile`` wrote: where, the periods carried, the file's sha256 before and after."""

    path: Path
    periods_s: tuple[float, ...]
    as_is_s: tuple[float, ...]
    sha256_before: str
    sha256_after: str
    #: The periods whose equations the file carried for other TFs (a sub-model's tf changed by
    #: hand or by a tool after they were written), derived anew from the file's TFs.
    stale_s: tuple[float, ...] = ()


def compile_file(source: Path, periods_s: Iterable[float], out: Path | None = None) -> Compiled:
    """Write ``source`` (or a copy at ``out``) with difference equations at ``periods_s``.

    Periods the file already carries are derived anew and kept; a period the
    model runs at as it is (its discrete TFs at their own rate) needs none.
    Raises :class:`ModelFileError` naming the file and the sub-model when a
    period cannot be reached (e.g. a pole with no continuous equivalent).
    """
    model_file, carried_s, stale_s = _read_for_compiling(Path(source))
    model = model_file.model
    wanted = sorted({float(p) for p in periods_s} | set(carried_s))
    sets: list[DifferenceEquations] = []
    as_is: list[float] = []
    for period_s in wanted:
        if any(same_period(period_s, s.period_s) for s in sets):
            continue
        if not model_needs_conversion(model, period_s):
            as_is.append(period_s)
            continue
        try:
            sets.append(derive(model, period_s))
        except ModelError as exc:
            raise ModelFileError(
                model_file.path,
                f"cannot run at {period_s:g} s: {exc.message}",
                where=exc.where,
                fix="Choose a loop period the model can be brought to, or re-identify it at that "
                "period",
            ) from exc
    if len(sets) > MAX_PERIODS:
        raise ModelFileError(
            model_file.path,
            f"{len(sets)} periods asked; a model file carries at most {MAX_PERIODS}",
            fix="Ask for the periods your configs tick at",
        )
    raw = read_limited(Path(model_file.path), ModelFileError)
    text = with_equations(raw.decode("utf-8"), equations_lines(model, sets))
    sha256_before = hashlib.sha256(raw).hexdigest()
    destination = Path(model_file.path) if out is None else out
    # A stacked model's forest goes with it: the copy names the same sidecar beside itself.
    copy_sidecars(residual_files(model_file.doc), model_file.path, destination)
    if destination.parent.resolve() != Path(model_file.path).parent.resolve():
        text = _moved_provenance(model_file, text, destination)
    written = text.encode("utf-8")
    checked = parse_model_bytes(written, destination)  # what it writes, compd reads
    mode = destination.stat().st_mode & 0o777 if destination.exists() else None
    write_atomic(destination, written)
    if mode is not None:
        destination.chmod(mode)  # rewritten in place: as readable as it was
    periods = tuple(s.period_s for s in sets)
    return Compiled(
        destination, periods, tuple(as_is), sha256_before, checked.sha256, tuple(stale_s)
    )


def _read_for_compiling(source: Path) -> tuple[ModelFile, tuple[float, ...], tuple[float, ...]]:
    """The model file without its equations, the periods it carried them at, and those carried
    for other TFs.

    The section is what this command writes anew, so it is not held against
    the file here as every other reader holds it (equations derived from TFs
    the file no longer has: its ``tf`` edited after they were written).
    """
    path = model_source(source)
    text = read_limited(path, ModelFileError).decode("utf-8")
    data, _ = parse_yaml(text, path, ModelFileError)  # bounded, as every model file is read
    model_file = parse_model(with_equations(text, []), path)
    digest = tfs_sha256(model_file.model)
    carried, stale = [], []
    sets = data.get("difference_equations") if isinstance(data, dict) else None
    for entry in sets if isinstance(sets, list) else ():
        period_s = entry.get("period_s") if isinstance(entry, dict) else None
        if isinstance(period_s, int | float) and period_s > 0:
            carried.append(float(period_s))
            if entry.get("tfs_sha256") != digest:
                stale.append(float(period_s))
    return model_file, tuple(carried), tuple(stale)


def _moved_provenance(model_file: ModelFile, text: str, destination: Path) -> str:
    """``text`` with its provenance's paths (relative to the source's folder) seen from ``destination``'s.

    Without it a copy elsewhere names other files, or none: ``compd report``
    no longer sees that a record is the one the model was fitted on. The block
    is rewritten only where it is the file's last, as compd writes it; a file
    arranged otherwise by hand is copied as it is.
    """
    moved = with_portable_provenance(
        text, destination, parent=model_file.doc.provenance, parent_path=Path(model_file.path)
    )
    before = parse_model(text, model_file.path).doc
    after = parse_model(moved, model_file.path).doc
    unchanged = before.model_copy(update={"provenance": after.provenance}) == after
    return moved if unchanged else text
