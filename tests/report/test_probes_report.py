"""``compd report --probe-every``: the probe updates drawn beside the open loop, as compare judges them."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from compd.cli import main
from tests.report.conftest import DATA, SEED000, cli_json

PROBES = ("--probe-every", "2h", "--seed", "3")


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> str:
    out = tmp_path_factory.mktemp("probes") / "probes.html"
    assert main(["report", str(SEED000), str(DATA), "--out", str(out), *PROBES]) == 0
    return out.read_text(encoding="utf-8")


def embedded(html: str, output: str) -> dict:
    found = re.search(
        rf'<script type="application/json" id="compd-probes-{output}">\n(.*?)\n</script>',
        html,
        re.S,
    )
    assert found is not None, "the report embeds the probe run as compare --json prints it"
    return json.loads(found.group(1))


def test_the_report_holds_what_compare_prints_with_the_same_probes(report: str) -> None:
    """Every figure of the probe section is compare --probe-every --json's, to the last digit."""
    compared = cli_json("compare", SEED000, DATA, "--json", *PROBES)["outputs"]["disp_z_um"]
    assert embedded(report, "disp_z_um") == compared
    assert compared["with_probes"]["fit_percent"] > compared["open_loop"]["fit_percent"]


def test_the_section_shows_open_loop_beside_the_updates_and_each_probe(report: str) -> None:
    """A table of both runs and the change, a figure with the probes marked, a row per probe."""
    run = embedded(report, "disp_z_um")
    section = report[report.index('id="probes-disp_z_um"') :]
    open_loop, probed = run["open_loop"]["fit_percent"], run["with_probes"]["fit_percent"]
    assert f"<td>open loop</td><td>{open_loop:.1f}</td>" in section
    assert f"<td>with probe updates</td><td>{probed:.1f}</td>" in section
    assert f"<td>change</td><td>+{probed - open_loop:.1f}</td>" in section
    steps = section[section.index('<table class="probe-steps">') :]
    rows = steps[: steps.index("</table>")].count("<tr>") - 1
    assert rows == len(run["probes"]) >= 3
    figure = section[section.index('id="fig-disp_z_um-probes"') :]
    figure = figure[: figure.index("</script>")]
    assert '"name":"with probe updates"' in figure and '"name":"probe accepted"' in figure


def test_probes_over_several_records_are_refused_naming_the_fix(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The update carries over one run: two files are refused, as compare refuses them."""
    out, second = tmp_path / "r.html", tmp_path / "second.csv"
    second.write_bytes(DATA.read_bytes())
    code = main(["report", str(SEED000), str(DATA), str(second), "--out", str(out), *PROBES])
    assert code != 0 and not out.exists()
    assert "one record" in capsys.readouterr().err
