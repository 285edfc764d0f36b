"""Machine variants: same inputs, different physics, and a clear error for an unknown name."""

from __future__ import annotations

import numpy as np
import pytest

from compd.cli import main
from compd.errors import ScenarioError
from compd.sim import simulate_scenario
from compd.sim.variants import VARIANTS, machine_variant


def test_each_variant_changes_the_displacement_but_not_the_inputs() -> None:
    """A variant is another machine under the same schedule: same spindle speeds, other TCP drift."""
    runs = {
        name: simulate_scenario("speed_spectrum", 4, seed=5, sample_time_s=30.0, params=params)
        for name, (params, _) in VARIANTS.items()
    }
    reference = runs["reference"]
    for name, run in runs.items():
        np.testing.assert_array_equal(run.spindle_speed_rpm, reference.spindle_speed_rpm)
        if name != "reference":
            assert np.abs(run.disp_z_um - reference.disp_z_um).max() > 5.0, name


def test_an_unknown_variant_lists_the_known_ones() -> None:
    """Asking for a variant that does not exist names every one that does."""
    with pytest.raises(ScenarioError, match="spindle-head"):
        machine_variant("turbo")


def test_twin_writes_a_variant_run(tmp_path) -> None:
    """``compd twin --variant spindle-head`` writes the run of that machine."""
    out = tmp_path / "head.csv"
    argv = ["twin", "--scenario", "calibration", "--hours", "2", "--sample-time-s", "30"]
    assert main([*argv, "--variant", "spindle-head", "--out", str(out)]) == 0
    assert out.read_text().startswith("time_s,")


def test_twin_help_lists_the_variants(capsys) -> None:
    """``compd twin --help`` renders and names every variant."""
    with pytest.raises(SystemExit):
        main(["twin", "--help"])
    text = capsys.readouterr().out
    assert all(name in text for name in VARIANTS)
