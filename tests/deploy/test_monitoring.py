"""deploy/prometheus and deploy/grafana: alert rules promtool accepts and whose unit tests pass, a fleet dashboard,
both naming only metrics a real compd exports."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.metricsrender import Render, rendered_with_broker
from tests.mosquitto import mosquitto_binary

DEPLOY = Path(__file__).parents[2] / "deploy"
RULES = DEPLOY / "prometheus" / "compd.rules.yml"
RULES_TEST = DEPLOY / "prometheus" / "compd.rules.test.yml"
DASHBOARD = DEPLOY / "grafana" / "compd-fleet.json"
PROMTOOL = shutil.which("promtool")
#: Series Prometheus itself adds to every target, beside what compd exports.
PROMETHEUS_OWN = {"up"}
#: The alerts docs/fleet.md ("Metrics and the status page") promises a shop.
ALERTS = {
    "CompdDown",
    "CompdAbsent",
    "CompdTicksStale",
    "CompdInputFaulted",
    "CompdOffsetMismatch",
    "CompdClampReached",
    "CompdModelFailure",
    "CompdStandingBy",
}
#: Grafana's variables, as a PromQL parser sees them once Grafana has filled them in.
GRAFANA_VARIABLES = {"$__rate_interval": "5m", "$machine_id": "mill-a"}

needs_promtool = pytest.mark.skipif(
    PROMTOOL is None,
    reason="promtool is missing: .ci/install-system-packages installs Debian's prometheus",
)


def metric_names(expr: str) -> set[str]:
    """The series an expression selects: identifiers before a ``{``, ``[`` or the end, not functions or labels."""
    without_strings = re.sub(r'"[^"]*"', '""', expr)
    without_labels = re.sub(r"\{[^}]*\}", "{}", without_strings)
    groupings = r"\b(by|without|on|ignoring|group_left|group_right)\s*\([^)]*\)"
    without_groupings = re.sub(groupings, "", without_labels)
    # A name a selector ends: a brace, a range, a bracket, an operator, a set operator, the end.
    selector = r"[a-zA-Z_:][a-zA-Z0-9_:]*(?=\s*(?:\{|\[|\)|$|\s*[-+*/=<>!]|\s+(?:or|and|unless)\b))"
    names = set(re.findall(selector, without_groupings))
    keywords = {"or", "and", "unless", "bool", "offset", "le", "time", "vector"}
    return {n for n in names if n not in keywords and not re.fullmatch(r"\d+\w*", n)}


def rules() -> list[dict[str, Any]]:
    doc = yaml.safe_load(RULES.read_text())
    return [rule for group in doc["groups"] for rule in group["rules"]]


def dashboard_exprs() -> list[str]:
    doc = json.loads(DASHBOARD.read_text())
    return [t["expr"] for panel in doc["panels"] for t in panel.get("targets", [])]


@pytest.fixture(scope="module")
def render(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Render]:
    """A real ``/metrics`` of compd with MQTT, recorder and http on (mosquitto on 127.0.0.1)."""
    if mosquitto_binary() is None:
        pytest.skip("mosquitto is not installed: run .ci/install-system-packages")
    with rendered_with_broker(tmp_path_factory.mktemp("monitoring")) as render:
        yield render


def test_metric_names_are_read_out_of_promql() -> None:
    """The helper finds the series of a join, a rate and a histogram quantile, and no label or function."""
    expr = (
        "histogram_quantile(0.99, sum by (le) (rate(a_bucket[5m]) * on(instance) "
        'group_left(machine_id) b{x="y"})) or up == 0'
    )
    assert metric_names(expr) == {"a_bucket", "b", "up"}


@needs_promtool
def test_promtool_accepts_the_rules_and_their_unit_tests_pass() -> None:
    """``promtool check rules`` passes the rules; ``promtool test rules`` their tests (two machines, one healthy)."""
    checked = subprocess.run([PROMTOOL, "check", "rules", str(RULES)], capture_output=True, text=True)  # fmt: skip
    assert checked.returncode == 0, checked.stdout + checked.stderr
    tested = subprocess.run(
        [PROMTOOL, "test", "rules", RULES_TEST.name],
        cwd=RULES_TEST.parent,
        capture_output=True,
        text=True,
    )
    assert tested.returncode == 0 and "SUCCESS" in tested.stdout, tested.stdout + tested.stderr


def test_every_promised_alert_exists_and_is_unit_tested_firing() -> None:
    """Daemon down and absent, stale ticks, a faulted input, offset mismatches, clamp reached, model failure."""
    names = {rule["alert"] for rule in rules()}
    assert names >= ALERTS
    tests = yaml.safe_load(RULES_TEST.read_text())["tests"]
    fired = {
        case["alertname"]
        for test in tests
        for case in test["alert_rule_test"]
        if case.get("exp_alerts")
    }
    assert fired == names


def test_rules_and_dashboard_name_only_metrics_compd_exports(render: Render) -> None:
    """Every series an alert or a dashboard panel selects is in a real ``/metrics`` render (or Prometheus's ``up``)."""
    exported = render.families | PROMETHEUS_OWN
    for expr in [rule["expr"] for rule in rules()] + dashboard_exprs():
        names = metric_names(expr)
        assert names, expr
        assert names <= exported, (expr, names - exported)


def test_dashboard_repeats_a_row_per_machine_with_offsets_fit_and_faults() -> None:
    """The dashboard parses; a machine_id variable from compd_info; a row repeated per machine; offsets, fit, faults."""
    doc = json.loads(DASHBOARD.read_text())
    variables = {v["name"]: v for v in doc["templating"]["list"]}
    assert "compd_info" in variables["machine_id"]["definition"]
    assert variables["machine_id"]["multi"] and variables["machine_id"]["includeAll"]
    rows = [p for p in doc["panels"] if p["type"] == "row"]
    assert len(rows) == 1 and rows[0]["repeat"] == "machine_id"
    exprs = " ".join(dashboard_exprs())
    for metric in ("compd_offset_meters", "compd_model_fit_ratio", "compd_faults_total"):
        assert metric in exprs
    for expr in dashboard_exprs():
        assert 'machine_id="$machine_id"' in expr, expr


@needs_promtool
def test_dashboard_queries_are_valid_promql(tmp_path: Path) -> None:
    """Each panel's query, its Grafana variables filled in, parses as PromQL (``promtool check rules``)."""
    records = []
    for k, expr in enumerate(dashboard_exprs()):
        for variable, value in GRAFANA_VARIABLES.items():
            expr = expr.replace(variable, value)
        records.append({"record": f"dashboard:query_{k}", "expr": expr})
    path = tmp_path / "dashboard.rules.yml"
    path.write_text(yaml.safe_dump({"groups": [{"name": "dashboard", "rules": records}]}))
    checked = subprocess.run([PROMTOOL, "check", "rules", str(path)], capture_output=True, text=True)  # fmt: skip
    assert checked.returncode == 0, checked.stdout + checked.stderr
