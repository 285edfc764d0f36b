"""The soak's faults (:mod:`compd.sim.soakfaults`): a seeded draw of every kind, bad files that really are bad."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest

from compd.errors import CompdError
from compd.service.modelload import slot_from_bytes
from compd.sim.soak import soak_config
from compd.sim.soakfaults import FAULT_KINDS, bad_models, draw_faults


def test_the_fault_draw_covers_every_kind_first_and_is_seeded():
    """The first faults are one of each kind; the same seed draws the same faults, 2-6 min apart."""
    faults = draw_faults(8 * 3600, 1)
    assert {f.kind for f in faults[: len(FAULT_KINDS)]} == set(FAULT_KINDS)
    assert faults == draw_faults(8 * 3600, 1) != draw_faults(8 * 3600, 2)
    assert all(120 <= b.at_s - a.at_s <= 360 for a, b in itertools.pairwise(faults))


def test_every_bad_model_is_refused_by_the_daemons_check(tmp_path: Path):
    """Gain 1e308, nk 10^6, a pole at 1.2 and garbage bytes, made from the bundled model, are each refused."""
    config = soak_config(tmp_path, hours=1, seed=1)
    bad = bad_models(config.model_path.read_bytes())
    assert set(bad) == {"gain_1e308", "nk_1e6", "unstable", "garbage"}
    for name, raw in bad.items():
        with pytest.raises(CompdError):
            slot_from_bytes(config, raw, name, 0.0)
