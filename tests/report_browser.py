"""Opening a report in a real headless browser: Playwright driving the system's Chromium
(Debian's /usr/bin/chromium, or STEPZOO_CHROMIUM), with every network request refused and
recorded, so a page that needs one is caught. The browser test uses it, and so does the
README's screenshot:

    python tests/report_browser.py results/report/index.html docs/report.png [SECTION_ID]
"""
from __future__ import annotations

import os
import shutil
import sys
from contextlib import contextmanager
from pathlib import Path

ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]
RENDER_TIMEOUT_MS = 60_000


def chromium() -> str | None:
    """The Chromium executable, or None when this machine has none."""
    given = os.environ.get("STEPZOO_CHROMIUM")
    for path in (given, shutil.which("chromium"), "/usr/bin/chromium"):
        if path and Path(path).is_file() and os.access(path, os.X_OK):
            return path
    return None


def unavailable() -> str | None:
    """Why no browser test can run here, or None when one can."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is not installed (pip install -e '.[test]')"
    if chromium() is None:
        return ("no Chromium at /usr/bin/chromium (apt-get install chromium) nor "
                "STEPZOO_CHROMIUM")
    return None


class Visit:
    """What the page did: console errors, uncaught exceptions, refused network requests."""

    def __init__(self, page):
        self.page, self.errors, self.requests = page, [], []
        page.on("console", lambda m: m.type == "error" and self.errors.append(m.text))
        page.on("pageerror", lambda e: self.errors.append(str(e)))
        page.route("**/*", self._route)

    def _route(self, route):
        url = route.request.url
        if url.startswith(("file:", "data:", "blob:", "about:")):
            route.continue_()
        else:
            self.requests.append(url)
            route.abort()

    def plots(self) -> list[dict]:
        """Per Plotly plot: its id, whether it drew an SVG, and how many traces it drew."""
        return self.page.evaluate("""() => [...document.querySelectorAll('.plotly-graph-div')]
            .map(d => ({id: d.id, svg: d.querySelectorAll('svg.main-svg').length,
                        traces: d.querySelectorAll('.scatterlayer .trace').length}))""")

    def overflow_px(self) -> int:
        """How far the page is wider than the window [CSS px] (0: no sideways scrolling)."""
        return self.page.evaluate(
            "() => Math.max(document.documentElement.scrollWidth, document.body.scrollWidth)"
            " - window.innerWidth")


@contextmanager
def visit(index, width: int = 1280, height: int = 900):
    """Open the report `index` (a path) at a window `width` x `height` [CSS px] and wait
    until every Plotly plot has drawn; yields a Visit."""
    from playwright.sync_api import sync_playwright
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium(), args=ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": width, "height": height})
            seen = Visit(page)
            page.goto(Path(index).absolute().as_uri(), wait_until="load",
                      timeout=RENDER_TIMEOUT_MS)
            page.wait_for_function(
                """() => [...document.querySelectorAll('.plotly-graph-div')]
                   .every(d => d.querySelector('svg.main-svg'))""", timeout=RENDER_TIMEOUT_MS)
            yield seen
        finally:
            browser.close()


def screenshot(index, png, section: str = "fig5", width: int = 900, height: int = 1000):
    """The window scrolled to the element `section` (an id, default Figure 5), as a PNG."""
    with visit(index, width, height) as seen:
        seen.page.evaluate(f"document.getElementById({section!r}).scrollIntoView()")
        seen.page.screenshot(path=str(png))


if __name__ == "__main__":
    if len(sys.argv) not in (3, 4):
        sys.exit(__doc__.split("\n\n")[1])
    screenshot(*sys.argv[1:])
