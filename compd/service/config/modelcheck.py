"""Whether a config can run a model: every input a signal in its unit, every axis an output, every gain a name.

Checked at start-up, by ``check-config`` and on each model load (local or
rolled out), before the model reaches the loop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from compd.errors import ConfigFileError
from compd.files.yamlplace import where
from compd.service.config.unitcheck import unit_problem
from compd.service.loop.schedule import model_gains

if TYPE_CHECKING:
    from compd.files.modelfile import ModelFile
    from compd.model.compiled import CompiledModel
    from compd.service.config.docs import GainScheduleDoc
    from compd.service.config.loading import Config


def check_model(config: Config, model_file: ModelFile, compiled: CompiledModel) -> None:
    """Refuse a model this config cannot run: an input without a signal, an axis without an output."""
    missing = [s for s in compiled.signals if s not in config.doc.signals]
    if missing:
        raise ConfigFileError(
            config.path,
            f"model {model_file.path} reads signal(s) {missing} that are not defined",
            where="signals",
            fix=f"Add them under 'signals' (defined: {sorted(config.doc.signals)})",
        )
    for name, signal in config.doc.signals.items():
        if signal.redundant is not None and signal.redundant in compiled.signals:
            raise ConfigFileError(
                config.path,
                f"partner {signal.redundant!r} of signal {name!r} is an input of model "
                f"{model_file.path}: a second sensor stands in for its input, it is not one",
                where=where(config.root, ("signals", name, "redundant")),
                fix=f"Name a signal the model does not read as the partner, or refit the model "
                f"without {signal.redundant!r}",
            )
    units = model_file.signal_units() or {}
    for name in compiled.signals:
        declared = units.get(name)
        if declared is None:
            continue
        signal = config.doc.signals[name]
        problem = unit_problem(signal.unit, declared, signal.scale, signal.offset)
        if problem is not None:
            raise ConfigFileError(
                config.path,
                f"signal {name!r} is in {signal.unit!r}, and model {model_file.path} reads it "
                f"in {declared!r}: {problem[0]}",
                where=where(config.root, ("signals", name, "unit")),
                fix=problem[1],
            )
    for axis, output in config.doc.outputs.items():
        if output.model_output not in compiled.output_names:
            raise ConfigFileError(
                config.path,
                f"model {model_file.path} has no output {output.model_output!r}",
                where=f"outputs.{axis}.model_output",
                fix=f"Use one of {list(compiled.output_names)}",
            )
    if config.doc.gain_schedule is not None:
        _check_gain_names(config, config.doc.gain_schedule, model_file, compiled)


def _check_gain_names(
    config: Config, schedule: GainScheduleDoc, model_file: ModelFile, compiled: CompiledModel
) -> None:
    """Every gain the schedule sets must be a ``gain_name`` of the model."""
    known = model_gains(compiled)
    places: list[tuple[tuple[str | int, ...], dict[str, float]]] = [
        (("gain_schedule", "table", i, "gains"), row.gains) for i, row in enumerate(schedule.table)
    ]
    if schedule.default is not None:
        places.append((("gain_schedule", "default"), schedule.default))
    for location, gains in places:
        for name in gains:
            if name not in known:
                fix = (
                    f"Use one of {sorted(known)}"
                    if known
                    else "Name the gains in the model file ('gain_name: g1' on the sub-models "
                    "they scale, Post-process 2024, eq. 6), or remove 'gain_schedule'"
                )
                raise ConfigFileError(
                    config.path,
                    f"model {model_file.path} has no gain named {name!r}",
                    where=where(config.root, (*location, name)),
                    fix=fix,
                )
