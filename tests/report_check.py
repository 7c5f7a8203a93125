"""Opens a scorecard's report.html in a real headless browser (Debian's chromium, driven by
Playwright) and checks what a reader sees: the page loads with no console error and no request
beyond the file itself, the summary table has one column per filter and its failing items
first, and every figure is drawn (visible, with a size).

    python tests/report_check.py DIR/report.html FILTERS [SCREENSHOT.png]

Prints "ok: N figures, F filter columns, R rows" or exits non-zero with the reason.
"""
import pathlib
import sys

from playwright.sync_api import sync_playwright

CHROMIUM = "/usr/bin/chromium"
# Without the background-networking flags chromium tries hosts this closed machine refuses.
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def main() -> int:
    report = pathlib.Path(sys.argv[1]).resolve()
    filters = int(sys.argv[2])
    screenshot = sys.argv[3] if len(sys.argv) > 3 else None
    problems: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.on("console", lambda m: problems.append(f"console {m.type}: {m.text}") if m.type in ("error", "warning") else None)
        page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
        page.on("requestfailed", lambda r: problems.append(f"request failed: {r.url}"))
        # Self-contained: the file itself is the only request.
        page.on("request", lambda r: problems.append(f"requested {r.url}") if r.url != report.as_uri() else None)
        page.goto(report.as_uri(), wait_until="load")
        columns = page.locator("#summary-table thead th.filter").count()
        if columns != filters:
            problems.append(f"the summary table has {columns} filter columns, expected {filters}")
        rows = page.locator("#summary-table tbody tr")
        items = [r for r in rows.all() if r.locator("a").count() > 0]
        failing = ["fail" in (r.inner_html()) or "error" in r.inner_html() for r in items]
        # Failing items first: no failing row after a row that does not fail.
        if any(f and not g for g, f in zip(failing, failing[1:])):
            problems.append("a failing item comes after one that does not fail")
        figures = page.locator("figure svg").all()
        if not figures:
            problems.append("no figure")
        for i, f in enumerate(figures):
            f.scroll_into_view_if_needed()
            box = f.bounding_box()
            if not f.is_visible() or box is None or box["width"] < 50 or box["height"] < 30:
                problems.append(f"figure {i} is not drawn (box {box})")
            # Drawn content: shapes inside, not an empty frame.
            if f.locator("rect, polyline, line, circle").count() == 0:
                problems.append(f"figure {i} has nothing drawn in it")
        if screenshot:
            page.screenshot(path=screenshot, full_page=False)
        browser.close()
    if problems:
        print("\n".join(problems[:20]), file=sys.stderr)
        return 1
    print(f"ok: {len(figures)} figures, {columns} filter columns, {len(items)} rows")
    return 0


if __name__ == "__main__":
    sys.exit(main())
