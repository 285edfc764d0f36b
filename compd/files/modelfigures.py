"""Whose each figure in a model file is: the model's own headline, and its base model's, labelled.

A model file records fit % figures in its provenance. ``compd fit`` writes
the fitted model's: the expected fit on new data (the median of its nested
held-out folds), its fit on the calibration record. ``compd extend`` writes a
new model, and its figures must be that model's: its fit on a record it was
not fitted on (``--verify``) or on held-out parts of the extension record,
its fit on the extension record; the base model's figures move to
``provenance.base_model``, named as the base model's
(:func:`derived_provenance`). Files written before that keep the fitted
model's figures beside their extensions; :func:`model_figures` reads both
kinds and says whose each figure is, so ``compd model check`` and the report
never print a base model's figure as an extended model's.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from compd.files.modelschema import (
    BaseModelDoc,
    CrossValidationDoc,
    ExtensionDoc,
    HeadlineDoc,
    ModelDoc,
    ProvenanceDoc,
)

#: The headline figures' names, in the words ``compd fit``, ``extend``, ``model check`` and the report use.
EXPECTED = "expected fit on new data"
VERIFIED = "fit on new data"
HELD_OUT = "held-out fit"


def fit_headline(
    cross_validation: CrossValidationDoc, model: str, method: str | None = None
) -> HeadlineDoc | None:
    """``compd fit``'s headline: the expected fit on new data of ``method``'s model (None: not judged).

    ``method``: the method that identified the model the file holds
    (``provenance.method``). Cross-validation keeps the candidate that held best
    (``kept``), and a fit with ``--method oe`` (or the default with a gate)
    writes another: then the figure is this model's only where the folds judged
    ``method`` too, and None where they did not (:func:`judged_other` says
    whose figure the folds have). Without ``method`` (files that do not record
    it): the kept candidate's.
    """
    credited = cross_validation.kept if method is None else method
    if credited != cross_validation.kept:
        if not _judged(cross_validation, credited):
            return None
        # The same figures and words, for the method the file's model was identified by.
        cross_validation = cross_validation.model_copy(update={"kept": credited})
    expected = cross_validation.expected_percent()
    if expected is None:
        return None
    kept = cross_validation.kept
    if kept in cross_validation.fold_median_percent:
        source = "fold_median_percent"
    elif kept in cross_validation.nested_fit_percent:
        source = "nested_fit_percent"
    else:
        source = "fit_percent"
    how = (
        "nested cross-validation"
        if kept in cross_validation.nested_fit_percent
        else "cross-validation, settings chosen on the same folds (optimistic)"
    )
    return HeadlineDoc(
        name=EXPECTED,
        percent={cross_validation.output: expected},
        model=model,
        description=f"{kept}, {how}{cross_validation.expected_how()}, {cross_validation.folds}",
        source=f"cross_validation.{source}.{kept}",
    )


def _judged(cross_validation: CrossValidationDoc, method: str) -> bool:
    """Whether the folds scored ``method`` (a held-out figure for it is recorded)."""
    return any(
        method in figures
        for figures in (
            cross_validation.fold_median_percent,
            cross_validation.nested_fit_percent,
            cross_validation.fit_percent,
        )
    )


def judged_other(prov: ProvenanceDoc, model: str) -> HeadlineDoc | None:
    """The cross-validated headline of the candidate the folds kept, where it is not this file's model.

    ``compd fit --method oe`` writes an OE model; its folds may have kept
    ``mlr``, and mlr's expected fit on new data is no figure of the OE model.
    None: the figure is this model's (or there is none).
    """
    cv = prov.cross_validation
    if cv is None or prov.method is None or prov.method == cv.kept or _judged(cv, prov.method):
        return None
    return fit_headline(cv, model)


def _credited(headline: HeadlineDoc | None, prov: ProvenanceDoc) -> HeadlineDoc | None:
    """A recorded headline, unless it repeats another method's cross-validated figure.

    Files written before ``fit_headline`` took the method recorded the kept
    candidate's figure as the headline of whatever model they held.
    """
    if headline is None or prov.method is None or not headline.source:
        return headline
    source = headline.source
    if source.startswith("cross_validation.") and source.rsplit(".", 1)[-1] != prov.method:
        return None
    return headline


def extension_headline(extension: ExtensionDoc, index: int, model: str) -> HeadlineDoc | None:
    """An extended model's headline: its fit on the ``--verify`` record, else on held-out folds.

    The verification record was used for nothing: the figure is the extended
    model's fit on new data. Without one, the held-out figure of the rule
    ``compd extend`` applied (the extension record's folds, the new sub-model
    fitted without each, the base model fixed). ``index``: the entry's place
    in ``provenance.extensions``.
    """
    if extension.verify_fit_percent_after and extension.verify_data:
        before = percent_text(extension.verify_fit_percent_before)
        return HeadlineDoc(
            name=VERIFIED,
            percent=dict(extension.verify_fit_percent_after),
            model=model,
            data=extension.verify_data,
            description="a record not used for fitting"
            + (f"; the model before this extension: {before}" if before else ""),
            source=f"extensions[{index}].verify_fit_percent_after",
        )
    kept = [t for t in extension.tried if t.kept]
    if not kept or not extension.fit_percent_after:
        return None
    (output, *_) = extension.fit_percent_after
    return HeadlineDoc(
        name=HELD_OUT,
        percent={output: kept[0].held_out_fit_percent_after},
        model=model,
        data=extension.data,
        description=f"its held-out parts ({kept[0].folds} folds), the new sub-model fitted "
        "without each; the model before this extension: "
        f"{kept[0].held_out_fit_percent_before:.1f} %",
        source=f"extensions[{index}].tried[kept].held_out_fit_percent_after",
    )


def derived_provenance(
    provenance: ProvenanceDoc,
    *,
    parent_name: str,
    parent_sha256: str,
    output: str,
    fit_percent: Mapping[str, float],
    fit_data: str,
) -> ProvenanceDoc:
    """``provenance`` for a model extended from the one it describes: the figures made this model's.

    The parent's fitted figures (headline, fit on its calibration,
    cross-validation, its notes) move to ``base_model``, once: a model extended twice
    keeps the fitted model as its base. ``fit_percent`` (on ``fit_data``)
    becomes this model's, for ``output``; the calibration's fit of ``output``
    is left out, as this model was not run over that record. The caller sets
    the new headline (it needs the last extension entry).
    """
    base = provenance.base_model
    if base is None:
        base = BaseModelDoc(
            name=parent_name,
            sha256=parent_sha256,
            data=provenance.data,
            fit_percent=dict(provenance.fit_percent),
            headline=_credited(provenance.headline, provenance)
            or (
                None
                if provenance.cross_validation is None
                else fit_headline(provenance.cross_validation, parent_name, provenance.method)
            ),
            cross_validation=provenance.cross_validation,
            notes=provenance.notes,
        )
    calibration = provenance.calibration
    if calibration is not None:
        calibration = calibration.model_copy(
            update={
                "fit_percent": {k: v for k, v in calibration.fit_percent.items() if k != output}
            }
        )
    own = {k: v for k, v in provenance.fit_percent.items() if k != output}
    return provenance.model_copy(
        update={
            "base_model": base,
            "calibration": calibration,
            "cross_validation": None,
            "fit_percent": {**own, **fit_percent},
            "fit_data": fit_data,
            "notes": "" if provenance.base_model is None else provenance.notes,
        }
    )


@dataclass(frozen=True)
class Figures:
    """A model file's figures, each said to be this model's or its base model's."""

    #: This model's headline (None: the file records none it can be credited with).
    headline: HeadlineDoc | None
    #: This model's fit on the data it was fitted on, and that data.
    fit_percent: Mapping[str, float]
    fit_data: str | None
    #: The model it was derived from, with that model's figures (None: fitted, not derived).
    base: BaseModelDoc | None
    #: Who the base is, in words: "the base model NAME (sha256 ...)".
    base_label: str
    #: Updates (``compd update``) after which none of the figures were measured again.
    updates: int = 0
    #: The cross-validated headline of the candidate the folds kept, where that is not the
    #: model this file holds (``--method oe``, the folds keeping mlr): never this model's.
    other: HeadlineDoc | None = None
    #: The method that identified this file's model (``provenance.method``; None: not recorded).
    method: str | None = None

    def not_judged(self) -> str | None:
        """``no expected fit on new data for this oe model: ...``; None unless :attr:`other`."""
        other = self.other
        if other is None:
            return None
        kept = other.source.rsplit(".", 1)[-1] if other.source else "another candidate"
        return (
            f"no {EXPECTED} for this {self.method} model: its cross-validation kept {kept} "
            f"({other.name} {percent_text(other.percent)}), a figure of {kept}'s model, "
            f"not of the {self.method} model this file holds"
        )


def model_figures(doc: ModelDoc) -> Figures:
    """The figures of ``doc``, whose each is, for files of every compd version.

    A file written before ``base_model`` existed and holding extensions keeps
    the fitted model's figures beside them: they are labelled the base
    model's, and the last extension's verification (else held-out) figure is
    this model's headline. ``compd update`` re-optimises gains and measures no
    headline: ``updates`` says how many came after the figures.
    """
    prov = doc.provenance
    extensions = prov.extensions
    other = None
    if prov.base_model is not None or not extensions:
        base = prov.base_model
        headline = _credited(prov.headline, prov) if base is None else prov.headline
        if headline is None and base is None and prov.cross_validation is not None:
            headline = fit_headline(prov.cross_validation, doc.name, prov.method)
            other = judged_other(prov, doc.name)
        fit, fit_data = dict(prov.fit_percent), prov.fit_data or prov.data
    else:  # an extended file of an older compd: the top-level figures are the fitted model's
        parent = extensions[0].parent_sha256
        base = BaseModelDoc(
            sha256=parent,
            data=prov.data,
            fit_percent=dict(prov.fit_percent),
            headline=None
            if prov.cross_validation is None
            else fit_headline(prov.cross_validation, "", prov.method),
            cross_validation=prov.cross_validation,
            notes=prov.notes,
        )
        headline = extension_headline(extensions[-1], len(extensions) - 1, doc.name)
        last = extensions[-1]
        fit, fit_data = dict(last.fit_percent_after), last.data
    label = ""
    if base is not None:
        name = f"the base model {base.name}" if base.name else "the base model"
        steps = len(extensions)
        label = (
            f"{name} (sha256 {base.sha256[:12]}, before its "
            f"{'extension' if steps == 1 else f'{steps} extensions'})"
        )
    return Figures(
        headline,
        fit,
        fit_data,
        base,
        label,
        updates=_updates_since(prov),
        other=other,
        method=prov.method,
    )


def _updates_since(prov: ProvenanceDoc) -> int:
    """The updates after the last extension (all of them without one): its figures predate them."""
    since = prov.extensions[-1].created if prov.extensions else None
    if since is None:
        return len(prov.updates)
    return sum(1 for u in prov.updates if u.created is None or u.created > since)


def figure_lines(figures: Figures) -> list[tuple[str, str]]:
    """The figures as ``compd model check`` and the report print them: (lead, rest) per line.

    This model's headline first, bold where shown, with its fit on the data it
    was fitted on; then the base model's, named as the base model's.
    """
    lines = []
    derived = figures.base is not None
    fitted = _fitted(figures.fit_percent, figures.fit_data if derived else None, derived)
    if figures.headline is not None:
        h = figures.headline
        lines.append((f"{h.name}: {percent_text(h.percent)}", f" ({headline_how(h)}){fitted}"))
    elif (said := figures.not_judged()) is not None:
        lines.append((said, fitted))
    elif fitted:
        lines.append(("", fitted.removeprefix("; ")))
    base = figures.base
    if base is not None:
        theirs = base.headline
        lead = f"{figures.base_label}: " + (
            f"{theirs.name} {percent_text(theirs.percent)} ({headline_how(theirs)})"
            if theirs is not None
            else "no figures"
        )
        lines.append(("", lead + _fitted(base.fit_percent, base.data)))
    if figures.updates and lines:
        lines.append(
            (
                "",
                f"measured before its {figures.updates} update(s): compd update re-optimised "
                "gains since (each update's fit is in its record)",
            )
        )
    return lines


def headline_how(headline: HeadlineDoc) -> str:
    """How a headline figure was measured, its record first when it names one."""
    return ", ".join(t for t in (headline.data, headline.description) if t)


def _fitted(percent: Mapping[str, float], data: str | None, extended: bool = False) -> str:
    if not percent:
        return ""
    what = "the data it was extended on" if extended else "the data it was fitted on"
    where = f"on {data}, {what}" if data else f"on {what}"
    return f"; {percent_text(percent)} {where}"


def percent_text(percent: Mapping[str, float]) -> str:
    """``95.4 %`` for one output, ``disp_x_um 95.4 %, disp_z_um 93.1 %`` for several."""
    return ", ".join(
        f"{v:.1f} %" if len(percent) == 1 else f"{k} {v:.1f} %" for k, v in percent.items()
    )
