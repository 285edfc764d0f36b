"""Headless Debian chromium for report tests, and a report-to-PNG helper for the README.

Playwright's driver runs the system's ``/usr/bin/chromium`` (no browser
download). ``python tests/report_screenshot.py MODEL.yaml DATA.csv OUT.png``
writes the report of MODEL on DATA and a full-page screenshot of it.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",  # CI and this machine run as root, where the sandbox cannot start
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
]
#: How long plotly may take to draw every figure of a report, in ms.
RENDER_TIMEOUT_MS = 30_000


def chromium_missing() -> str | None:
    """Why a browser test cannot run here, or None when it can."""
    if not Path(CHROMIUM).exists():
        return "chromium is not installed (CI installs it with .ci/install-system-packages)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is missing: pip install -e '.[test]'"
    return None


@contextmanager
def chromium() -> Iterator[Any]:
    """A headless Debian chromium driven by playwright, closed on exit."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


def wait_for_plots(page: Any, n_figures: int) -> None:
    """Wait until ``n_figures`` plotly figures have drawn their SVG."""
    page.wait_for_function(
        "n => document.querySelectorAll('.js-plotly-plot .main-svg').length >= n "
        "&& document.querySelectorAll('.js-plotly-plot').length >= n",
        arg=n_figures,
        timeout=RENDER_TIMEOUT_MS,
    )


def screenshot(report_html: Path, png: Path, *, width_px: int = 1280) -> Path:
    """A full-page PNG of a report file as headless chromium draws it."""
    from compd.report.page import FIGURE_CLASS

    with chromium() as browser:
        page = browser.new_page(viewport={"width": width_px, "height": 900})
        page.goto(report_html.resolve().as_uri())
        n = page.locator(f".{FIGURE_CLASS}").count()
        wait_for_plots(page, n)
        page.screenshot(path=str(png), full_page=True)
    return png


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", type=Path)
    parser.add_argument("data", type=Path)
    parser.add_argument("png", type=Path)
    parser.add_argument("--compare", type=Path, metavar="OTHER.yaml")
    parser.add_argument("--html", type=Path, help="keep the report here (default: a temp file)")
    args = parser.parse_args(argv)
    missing = chromium_missing()
    if missing:
        print(missing, file=sys.stderr)
        return 1
    from compd.files.data import load_data
    from compd.files.modelfile import load_model
    from compd.report import write_report
    from compd.toolkit.evaluate import evaluate

    data = load_data(args.data)
    other = None if args.compare is None else evaluate(load_model(args.compare), data)
    with tempfile.TemporaryDirectory() as tmp:
        html = args.html or Path(tmp) / "report.html"
        write_report(html, evaluate(load_model(args.model), data), other=other)
        screenshot(html, args.png)
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
