"""Input denoising for ``compd fit --denoise``: EMD offline, a matched causal low-pass in the model file.

Swiss-lathe paper (sect. 2.1) removes the first intrinsic mode function (IMF1, the
fastest oscillation found by EMD's sifting) from noisy temperature inputs,
such as an air-conditioned hall's ambient sensor cycling with the AC, before
identifying the model. The decomposition comes from PyEMD (PyPI
``EMD-signal``): cubic-spline envelopes through the extrema, sifted until
Huang's stoppage criterion holds.

EMD is not causal (each envelope passes through extrema after the sample),
so the service cannot run it. For each denoised input the fit therefore
also chooses the causal low-pass (:mod:`compd.model.lowpass`) whose output
on the calibration record is closest to the EMD-denoised input, and
multiplies it into that input's sub-model TFs. The written file reads the
raw sensor; its fit % (the one ``compd compare`` reproduces) is that of the
low-passed model, and the provenance keeps the EMD-driven figures beside it,
so the price of causality is on record.

Cost: PyEMD's sifting is about linear in the record length. Measured on
the twin's ambient sensor (two runs each): a day at 10 s (8,640 samples)
takes 0.07-0.15 s for IMF1, 0.15-0.4 s for four IMFs; a day at 1 s (86,400
samples) 3-4.5 s and 7.5-9 s.
That is affordable once per fit, so the whole record is decomposed at once
(no chunking, whose seams would add end effects of their own).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from compd.errors import DataFileError
from compd.files.data import DataSet
from compd.files.modelschema import DenoisedInputDoc, DenoiseDoc
from compd.model.compiled import compile_model
from compd.model.identify import Identification
from compd.model.lowpass import MatchedLowPass, cascade, match_lowpass
from compd.model.metrics import Comparison
from compd.model.run import simulate
from compd.model.structure import Model
from compd.model.transfer import DiscreteTF


def remove_first_imfs(x: np.ndarray, count: int = 1) -> np.ndarray:
    """``x - IMF1(x) - ... - IMFcount(x)``: the signal without its ``count`` fastest modes.

    Swiss-lathe paper (sect. 2.1) removes the first one (``count=1``). EMD acts on white
    noise as a dyadic filter bank (each IMF's mean period about twice the
    previous one's), so on a finely sampled noisy sensor IMF1 is mostly the
    sensor noise; an AC cycle of ~15 min at 10 s sampling sits in IMF4.
    A signal with fewer modes than ``count`` loses only those it has (a
    monotonic one has none and is returned unchanged).
    """
    if count < 1:
        raise ValueError(f"count of modes to remove must be >= 1, got {count}")
    # Imported here: PyEMD pulls in tqdm and pathos, which every other CLI call would pay for.
    from PyEMD import EMD  # type: ignore[import-untyped]  # the package ships no type hints

    x = np.asarray(x, dtype=float)
    emd = EMD()
    emd.emd(x, max_imf=count)
    # Separately, not as emd()'s stacked rows: a zero residue is left out of those.
    imfs, _ = emd.get_imfs_and_residue()
    denoised: np.ndarray = x - np.sum(imfs[:count], axis=0)
    return denoised


@dataclass(frozen=True, eq=False)
class DenoisedInput:
    """One input column: raw, EMD-denoised (first ``imfs_removed`` IMFs removed), its matched low-pass."""

    name: str
    raw: np.ndarray
    emd: np.ndarray
    matched: MatchedLowPass
    imfs_removed: int


def denoise_columns(
    data: DataSet, names: Sequence[str], inputs: Sequence[str], imfs: int = 1
) -> dict[str, DenoisedInput]:
    """Remove the first ``imfs`` EMD modes of columns ``names`` (each one of ``inputs``); match a low-pass to each."""
    unknown = [name for name in names if name not in inputs]
    if unknown:
        raise DataFileError(
            data.path,
            f"--denoise names {unknown}, which are not among the inputs {list(inputs)}",
            where="--denoise",
            fix="Denoise only columns that are also listed in --inputs",
        )
    if imfs < 1:
        raise DataFileError(
            data.path,
            f"the number of EMD modes to remove must be >= 1, got {imfs}",
            where="--denoise-imfs",
            fix="Use 1 (Swiss-lathe paper: the first mode) or more to remove slower cycles too",
        )
    result = {}
    for name in dict.fromkeys(names):
        raw = data.column(name)
        emd = remove_first_imfs(raw, imfs)
        matched = match_lowpass(raw, emd, data.sample_time_s)
        result[name] = DenoisedInput(name, raw, emd, matched, imfs)
    return result


@dataclass(frozen=True, eq=False)
class Baked:
    """A model with matched low-passes in its TFs, and its fit run on the raw inputs."""

    model: Model
    identification: Identification  # fit % and simulated output of the baked model, raw inputs
    doc: DenoiseDoc


def bake_lowpasses(
    model: Model,
    identification: Identification,
    data: DataSet,
    denoised: Mapping[str, DenoisedInput],
    units: Mapping[str, str],
) -> Baked:
    """Multiply each denoised input's matched low-pass into its sub-models' TFs; measure both models.

    ``identification`` was fitted on the EMD-denoised inputs; the returned
    one carries the baked model's free-run fit on the raw inputs (changes
    from start, started at rest: what ``compd compare`` reproduces).
    """
    sample_s = model.sample_time_s
    outputs = []
    for output in model.outputs:
        subs = []
        for sub in output.submodels:
            entry = denoised.get(sub.input.signal)
            if entry is not None:
                if not isinstance(sub.tf, DiscreteTF):
                    raise DataFileError(data.path, f"sub-model {sub.name!r} has no discrete TF")
                sub = dataclasses.replace(
                    sub, tf=cascade(sub.tf, entry.matched.lowpass.tf(sample_s))
                )
            subs.append(sub)
        outputs.append(dataclasses.replace(output, submodels=tuple(subs)))
    baked = dataclasses.replace(model, outputs=tuple(outputs))
    compiled = compile_model(baked)
    signals = np.vstack([data.column(name) for name in compiled.signals]).T
    simulated = simulate(compiled, signals, compiled.rest_state(signals[0]))
    name = model.outputs[0].name
    y = data.column(name)
    emd_run = Comparison.of(name, y, identification.simulated_um)
    raw_run = Comparison.of(name, y, simulated.output(compiled, name))
    doc = DenoiseDoc(
        method="emd-first-imfs",
        inputs=[
            DenoisedInputDoc(
                input=entry.name,
                unit=units.get(entry.name, "-"),
                imfs_removed=entry.imfs_removed,
                lowpass_tau_s=entry.matched.lowpass.tau_s,
                lowpass_stages=entry.matched.lowpass.stages,
                lowpass_vs_emd_rms=entry.matched.rms_degC,
                raw_vs_emd_rms=entry.matched.raw_rms_degC,
            )
            for entry in denoised.values()
        ],
        fit_percent_emd={name: emd_run.fit_percent},
        rms_um_emd={name: emd_run.residue.rms_um},
        fit_percent_lowpass={name: raw_run.fit_percent},
        rms_um_lowpass={name: raw_run.residue.rms_um},
    )
    raw_identification = dataclasses.replace(
        identification,
        fit_percent=raw_run.fit_percent,
        simulated_um=simulated.output(compiled, name),
    )
    return Baked(baked, raw_identification, doc)


def denoise_note(doc: DenoiseDoc) -> str:
    """One provenance sentence: what was denoised, with what, and what causality costs."""
    inputs = ", ".join(
        f"{i.input} ({i.imfs_removed} mode(s) removed; low-pass {i.lowpass_stages} x "
        f"{i.lowpass_tau_s:.0f} s, "
        f"{i.lowpass_vs_emd_rms:.4f} {i.unit} RMS from the EMD result)"
        for i in doc.inputs
    )
    (output, emd_fit), (_, lp_fit) = (
        next(iter(doc.fit_percent_emd.items())),
        next(iter(doc.fit_percent_lowpass.items())),
    )
    return (
        f"identified on inputs with their fastest EMD modes removed (Swiss-lathe paper): {inputs}; the "
        f"matched causal low-passes are multiplied into those TFs, so the file reads the raw "
        f"sensors: fit {lp_fit:.4f} % with them against {emd_fit:.4f} % on the EMD-denoised "
        f"inputs ({output})"
    )
