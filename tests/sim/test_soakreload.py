"""The soak's SIGHUP (:mod:`compd.sim.soakreload`): the config file as each variant leaves it for the reload."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.errors import CompdError
from compd.service.config.loading import load_config
from compd.sim.soak import soak_config
from compd.sim.soakreload import edited


def test_a_changed_config_differs_only_in_what_a_restart_applies_and_a_broken_one_is_refused(
    tmp_path: Path,
):
    """``unchanged`` reads the same; ``changed`` is valid with another ``live_every_ticks``; ``broken`` cannot load."""
    config = soak_config(tmp_path, hours=0.5, seed=1)
    text = config.path.read_text()
    assert edited(text, "unchanged") == text
    changed = tmp_path / "changed.yaml"
    changed.write_text(edited(text, "changed"))
    doc = load_config(changed).doc
    assert [f for f in type(doc).model_fields if getattr(doc, f) != getattr(config.doc, f)] == [
        "live_every_ticks"
    ]
    broken = tmp_path / "broken.yaml"
    broken.write_text(edited(text, "broken"))
    with pytest.raises(CompdError):
        load_config(broken)
