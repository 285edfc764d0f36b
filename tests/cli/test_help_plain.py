"""compd's help speaks plainly: no reStructuredText markup, papers cited by names a user can look up.

Help pages are read in a terminal: ``compd help config`` once showed
````value```` and ``:mod:`x```; command help said "Horejs 2015", which named
documents that do not ship with compd. Papers are cited by the short names
of ``compd help references``, which gives authors, title, venue and year.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from compd.cli import COMMANDS
from compd.cli.references import REFERENCES
from compd.cli.topicnames import TOPICS
from compd.cli.topics import help_text
from tests.drivers.modbus_server import free_port

ROOT = Path(__file__).parents[2]
MARKUP = re.compile(r"``|:[a-z]+:`")


@pytest.mark.parametrize("topic", ["config", "model-file"])
def test_schema_pages_have_no_restructuredtext_markup(topic):
    """compd help config and model-file show section notes without ``literals`` or :roles:."""
    page = help_text(topic)
    assert not MARKUP.findall(page), [line for line in page.splitlines() if MARKUP.search(line)]
    if topic == "config":
        assert "# 'value = raw * scale + offset' in 'unit'." in page
        assert "(see compd.service.loop.signals)" in page


def test_no_help_text_or_effect_says_seed():
    """No command's help, no topic page and no bundled effect text says 'seed 00N'."""
    pages = {"compd help": help_text(None)}
    pages |= {f"compd help {name}": help_text(name) for name in [*COMMANDS, *TOPICS]}
    effects = yaml.safe_load((ROOT / "config" / "effects.yaml").read_text())
    pages["config/effects.yaml"] = yaml.safe_dump(effects)
    said = {where: re.findall(r"[Ss]eeds? ?\d{3}", text) for where, text in pages.items()}
    assert not {where: found for where, found in said.items() if found}


def test_the_references_page_cites_the_papers_by_their_short_names():
    """compd help references gives each paper's short name, authors, title, venue, and the DOI printed."""
    page = help_text("references")
    for ref in REFERENCES:
        assert f"[{ref.short}]" in page and ref.title in page and ref.venue in page
    assert "Pahk" in page and "Horejš" in page
    assert "https://doi.org/10.1016/j.precisioneng.2024.02.011" in page
    cited = "\n".join(help_text(name) for name in COMMANDS)
    assert all(ref.short in cited for ref in REFERENCES if ref.short != "Horejs 2010")


def test_fits_one_line_help_names_the_lag_bank_it_uses_by_default():
    """compd help lists fit as identifying a lag bank by default, besides ARX, OE and MLR."""
    (line,) = [line for line in help_text(None).splitlines() if line.strip().startswith("fit ")]
    assert "by default a lag bank" in line and "ARX, OE or MLR" in line


def test_simulate_machine_says_what_it_serves_on_start(tmp_path):
    """compd simulate-machine's first line names the scenario, the controllers served and where."""
    doc = yaml.safe_load((ROOT / "config" / "simulated.yaml").read_text())
    port = free_port()
    doc["drivers"]["plc"]["settings"]["port"] = port
    doc["simulation"]["hours"] = 0.01  # 36 s of machine time
    doc["state"]["directory"] = str(tmp_path / "state")
    config = tmp_path / "sim.yaml"
    config.write_text(yaml.safe_dump(doc))
    argv = ["simulate-machine", "--config", str(config), "--time-scale", "1000"]
    done = subprocess.run(
        [sys.executable, "-m", "compd.cli", *argv],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        check=True,
    )
    first = done.stdout.splitlines()[0]
    assert first.startswith("simulated machine: production, 0.01 h, seed 1")
    assert f"plc (modbus, 127.0.0.1:{port})" in first
