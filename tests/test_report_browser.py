"""The report in a real headless browser (Playwright driving Chromium): it loads with no
console error and no network request, every interactive figure draws its traces, a click on
a legend entry hides that method, and at a phone's 390 px width nothing scrolls sideways.
Skipped, with the reason, where no browser is installed (see report_browser.py)."""
import pytest

import report_browser
from stepzoo.workflows.report import build
from helpers import write_plan, write_sweep, write_tuned

WHY_NOT = report_browser.unavailable()
pytestmark = [pytest.mark.e2e,
              pytest.mark.skipif(WHY_NOT is not None, reason=f"no browser test: {WHY_NOT}")]
PHONE_PX = 390


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    root = tmp_path_factory.mktemp("browser")
    write_sweep(root / "sweep")
    write_tuned(root / "tuned.toml")
    write_plan(root / "plans", "street")
    write_plan(root / "plans", "parking")
    index, _, _ = build(root / "sweep", root / "report", root / "tuned.toml", root / "plans")
    return index


def test_every_figure_draws_offline_without_errors(report):
    with report_browser.visit(report) as seen:
        plots = seen.plots()
        assert seen.errors == [] and seen.requests == []
    # Figures 1-6 have one plot each, Figure 7 one per plan.
    assert sorted(p["id"] for p in plots) == sorted(
        [f"plot{i}-1" for i in range(1, 7)] + ["plot7-1", "plot7-2"])
    for p in plots:
        assert p["svg"] >= 1 and p["traces"] >= 1, p


def test_a_legend_click_hides_that_method(report):
    with report_browser.visit(report) as seen:
        page = seen.page

        def shown():
            return page.evaluate("""() => document.getElementById('plot4-1').data
                .filter(t => t.visible !== 'legendonly' && t.visible !== false).length""")
        before = shown()
        page.locator("#plot4-1 .legend .traces").first.click()
        page.wait_for_function(f"() => document.getElementById('plot4-1').data.filter("
                               f"t => t.visible !== 'legendonly').length < {before}")
        # The method's measured line and its declared-slope line go together.
        assert shown() == before - 2
        assert seen.errors == []


def test_page_fits_a_phone(report):
    with report_browser.visit(report, width=PHONE_PX, height=844) as seen:
        assert seen.overflow_px() <= 0
        widths = seen.page.evaluate("""() => [...document.querySelectorAll(
            '.plotly-graph-div')].map(d => d.getBoundingClientRect().width)""")
        assert seen.errors == []
    assert all(0 < w <= PHONE_PX for w in widths), widths
