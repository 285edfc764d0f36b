"""Fit methods are chosen by name in one table; nothing else compares method names."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from compd.toolkit.fit import FitRequest
from compd.toolkit.methods import (
    EXTEND_METHODS,
    FIT_METHODS,
    METHODS,
    FitMethod,
    method_named,
    writes_lags,
)

ROOT = Path(__file__).resolve().parents[1] / "compd"
#: A method name compared as a string: ``method == "oe"``, ``x.method != 'mlr'``, ``method in ("a", "b")``.
COMPARED = re.compile(r"""method\s*(?:==|!=)\s*["']|method\s+(?:not\s+)?in\s*\(\s*["']""")


def test_no_method_name_is_compared_outside_the_table() -> None:
    """fit, candidates, nestedselect, extend, the CLI and identify ask a table, not an if-chain of names."""
    found = [
        f"{path.relative_to(ROOT.parent)}:{number}: {line.strip()}"
        for path in sorted(ROOT.rglob("*.py"))
        if path.relative_to(ROOT).as_posix() != "toolkit/methods.py"
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if COMPARED.search(line)
    ]
    assert found == []


def test_every_method_is_one_class_by_its_name() -> None:
    """The table maps each ``--method`` name to the class of that name; auto is the default."""
    assert FIT_METHODS[0] == "auto"
    assert set(EXTEND_METHODS) == set(FIT_METHODS) - {"mlr"}  # extend adds dynamics
    for name, cls in METHODS.items():
        assert issubclass(cls, FitMethod) and cls.name == name and cls.title
        assert method_named(name).name == name
    assert [name for name in METHODS if writes_lags(name)] == ["lagbank"]
    assert not writes_lags("not a method")


def test_auto_keeps_oe_for_structure_and_extends_by_oe_then_the_lag_bank() -> None:
    """auto with a gate, position or denoising is oe; extend's auto falls back to the lag bank."""
    auto = method_named("auto")
    assert auto.candidates(structured=False) == ("lagbank", "mlr")
    assert auto.candidates(structured=True) == ("mlr",)
    first, fallback = auto.for_extension()
    assert first.name == "oe" and fallback is not None and fallback.name == "lagbank"
    assert method_named("arx").for_extension()[1] is None


def test_a_request_is_frozen_and_keeps_sequences_as_tuples() -> None:
    """A fit request cannot change under the fit: lists given become tuples."""
    request = FitRequest(output="disp_z_um", inputs=["T1", "T2"], denoise=["T1"])
    assert request.inputs == ("T1", "T2") and request.denoise == ("T1",)
    with pytest.raises(dataclasses.FrozenInstanceError):
        request.method = "oe"  # type: ignore[misc]
