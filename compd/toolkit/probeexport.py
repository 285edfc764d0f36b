"""The model the probes taught, as a model file (``compd model export --updated``, issue 35 item 4).

The daemon runs ``y = f + x' theta`` per output (:mod:`compd.model.probelearner`):
``x`` the sub-models' contributions at the file's gains and 1. The file that
gives the same outputs multiplies each sub-model's gain by its learned
``theta_i`` and adds the learned bias to the output's ``bias_um``. Its
``probe_prior`` is the learner's posterior in the new file's parameters
(gains rescaled: ``P' = D^-1 P D^-1``, ``D = diag(theta_1 .. theta_n, 1)``),
so the exported model starts from what was learned; an output with a gain
learned to 0 gets the default prior instead. The provenance names the
probes: the parent's sha256 and every probe logged since the last reset.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compd import __version__
from compd.errors import ModelFileError
from compd.files.equations import kept_periods
from compd.files.modelfile import ModelFile, parse_model
from compd.files.modelschema import ProbePriorDoc, ProbeUpdateDoc, ProbeUsedDoc
from compd.files.modelwriter import model_to_yaml
from compd.files.probeprior import output_prior, probe_prior_doc
from compd.files.probestate import ProbeRecord, learned_path, read_log, restore_learners
from compd.model.probelearner import OutputLearner
from compd.model.proberegressors import output_columns
from compd.model.probesettings import ProbeSettings
from compd.model.structure import Output
from compd.model.updateprior import Prior


@dataclass(frozen=True)
class Export:
    """The updated model file's text, parsed, and what went into it."""

    text: str
    updated: ModelFile
    learned: dict[str, OutputLearner]
    probes: tuple[ProbeRecord, ...]
    notes: tuple[str, ...] = ()


def learned_learners(model_file: ModelFile, state_dir: Path) -> dict[str, OutputLearner]:
    """The learners the daemon saved for ``model_file`` (by its sha256); an error names the file and the fix.

    Read only: a damaged file is reported, not set aside (that is the daemon's to do).
    """
    compiled = model_file.compile()
    setups: dict[str, tuple[Prior, ProbeSettings]] = {}
    for output in compiled.output_names:
        prior = output_prior(model_file, output, output_columns(compiled, output)[1]).prior
        setups[output] = (prior, ProbeSettings.defaults(prior))
    path = learned_path(state_dir, model_file.sha256)
    if not path.exists():
        raise ModelFileError(
            model_file.path,
            f"no probe updates of this model (sha256 {model_file.sha256[:12]}) in {path.parent}",
            fix="Give the state directory of the daemon that ran it (--state-dir), and the very "
            "file it ran (a model is known by its sha256); 'compd model updates' lists the probes",
        )
    restored = restore_learners(state_dir, model_file.sha256, setups, set_aside_unreadable=False)
    if restored.problem is not None:
        raise ModelFileError(
            path,
            f"the probe updates cannot be read: {restored.problem}",
            fix="The daemon sets such a file aside at its next start and runs on the prior",
        )
    return {name: restored.learners[name] for name in restored.restored}


def export_updated(model_file: ModelFile, state_dir: Path, command: str | None = None) -> Export:
    """``model_file`` with what the probes taught it (see the module docstring)."""
    learned = learned_learners(model_file, state_dir)
    compiled = model_file.compile()
    doc = model_file.doc
    outputs = []
    priors: dict[str, ProbePriorDoc] = dict(doc.probe_prior or {})
    notes = []
    for output in model_file.model.outputs:
        learner = learned.get(output.name)
        if learner is None or not learner.updated:
            outputs.append(output)
            continue
        theta = learner.theta
        _, names = output_columns(compiled, output.name)
        # The multiplier of each sub-model's gain: its coefficient over the file's (1 per gain).
        gain_of = dict(zip(names, theta[:-1] / learner.prior.units[:-1], strict=True))
        outputs.append(
            Output(
                output.name,
                tuple(
                    dataclasses.replace(sub, gain=sub.gain * float(gain_of[sub.name]))
                    for sub in output.submodels
                ),
                output.residual,
                output.bias_um + float(theta[-1]),
            )
        )
        if learner.prior.form == "coefficients":
            # The new file's coefficients are the learned ones: the posterior is its prior as is.
            priors[output.name] = probe_prior_doc(
                dataclasses.replace(
                    learner.prior,
                    covariance=learner.updater.covariance.copy(),
                    coefficients=theta[:-1].copy(),
                )
            )
        elif np.all(theta[:-1] != 0.0):
            scale = np.append(theta[:-1], 1.0)
            covariance = learner.updater.covariance / np.outer(scale, scale)
            priors[output.name] = probe_prior_doc(
                dataclasses.replace(learner.prior, covariance=0.5 * (covariance + covariance.T))
            )
        else:
            priors.pop(output.name, None)
            notes.append(
                f"{output.name}: a gain was learned to 0: the exported file has no probe_prior "
                "for it, and its probe updates start from the documented default"
            )
    model = dataclasses.replace(model_file.model, outputs=tuple(outputs))
    log = read_log(state_dir)
    probes = _since_last_reset(log.records, model_file.sha256)
    record = ProbeUpdateDoc(
        parent_sha256=model_file.sha256,
        state=str(learned_path(state_dir, model_file.sha256)),
        probes=[
            ProbeUsedDoc(
                touched_s=p.touched_s,
                output=p.output,
                source=p.source,
                result=p.result,
                measured_um=p.measured_um,
                innovation_before_um=p.innovation_before_um,
                innovation_after_um=p.innovation_after_um,
            )
            for p in probes
        ],
        parameters={
            name: {n: float(v) for n, v in zip(learner.prior.names, learner.theta, strict=True)}
            for name, learner in learned.items()
        },
        created=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
    )
    provenance = doc.provenance.model_copy(
        update={
            "probe_updates": [*doc.provenance.probe_updates, record],
            "compd_version": __version__,
            "command": command or doc.provenance.command,
        }
    )
    residuals = {name: o.residual for name, o in doc.outputs.items() if o.residual is not None}
    text = model_to_yaml(
        model,
        description=doc.description,
        signals=model_file.signal_units(),
        provenance=provenance,
        residuals=residuals,
        consistency=doc.consistency,
        probe_prior=priors,
        run_periods_s=kept_periods(doc.difference_equations),
    )
    # Parsed beside the parent, where a residual model's sidecar is.
    updated = parse_model(text, model_file.path)
    return Export(text, updated, learned, probes, tuple(notes))


def _since_last_reset(records: tuple[ProbeRecord, ...], sha256: str) -> tuple[ProbeRecord, ...]:
    mine = [r for r in records if r.model_sha256 == sha256]
    resets = [i for i, r in enumerate(mine) if r.result == "reset"]
    return tuple(mine[resets[-1] + 1 :] if resets else mine)
