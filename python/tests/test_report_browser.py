"""report.html in headless Chromium (Debian's /usr/bin/chromium, driven by Playwright): every
plot drawn, no console error, no request beyond the page's own file, zoom works; a screenshot of
each page (into $AIFT_SCREENSHOTS when set, else the test's temporary folder)."""

import os
import pathlib
import shutil

import pytest

import playwright.sync_api as playwright  # a missing Playwright fails the run, not skips it

CHROMIUM = os.environ.get("AIFT_CHROMIUM", "/usr/bin/chromium")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


@pytest.fixture(scope="module")
def folders(tmp_path_factory, aift_bin, tiny_campaign):
    import subprocess

    base = tmp_path_factory.mktemp("reports")
    env = dict(os.environ)

    def aift(*args):
        p = subprocess.run([str(aift_bin), *map(str, args)], capture_output=True, text=True, env=env)
        assert p.returncode == 0, p.stderr

    aift("run", "--method", "pl-detect", "--out", base / "run")
    aift("table", "--set", "duration=9.0", "--methods", "no-ft,pl-always,oracle", "--seeds", "3",
         "--out", base / "table")
    (base / "c.toml").write_text(tiny_campaign("browser_tiny", methods=("no-ft", "pl-always", "oracle"),
                                              channels=("enc*", "cam")))
    aift("campaign", base / "c.toml", "--out", base / "campaign")
    return base


@pytest.fixture(scope="module")
def browser():
    if not pathlib.Path(CHROMIUM).is_file():
        pytest.fail(f"{CHROMIUM} is missing: install Debian's chromium (apt-get install chromium), as .ci/run does")
    with playwright.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        yield b
        b.close()


def open_report(browser, path, shots, name):
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    requests, errors = [], []
    page.on("request", lambda r: requests.append(r.url))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    url = path.resolve().as_uri()
    page.goto(url)
    page.wait_for_selector("body[data-plots-drawn]", timeout=30000)
    expected = page.evaluate("document.querySelectorAll('div.plot, svg.static, img.static').length")
    drawn = int(page.get_attribute("body", "data-plots-drawn"))
    failed = int(page.get_attribute("body", "data-plot-errors"))
    page.screenshot(path=str(shots / f"{name}.png"), full_page=False)
    return page, requests, errors, url, expected, drawn, failed


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    d = os.environ.get("AIFT_SCREENSHOTS")
    if d:
        p = pathlib.Path(d)
        p.mkdir(parents=True, exist_ok=True)
        return p
    return tmp_path_factory.mktemp("shots")


@pytest.mark.parametrize("kind,minimum", [("run", 6), ("table", 3), ("campaign", 1)])
def test_report_draws_every_plot_offline(browser, folders, shots, kind, minimum):
    path = folders / kind / "report.html"
    assert path.is_file(), f"aift {kind} wrote no report.html"
    page, requests, errors, url, expected, drawn, failed = open_report(browser, path, shots, kind)
    assert errors == [], errors
    assert requests == [url], f"requests beyond the page itself: {requests}"
    assert failed == 0
    assert drawn == expected >= minimum, (drawn, expected)
    assert (shots / f"{kind}.png").stat().st_size > 10_000
    assert_distinct_tick_labels(page)
    if kind == "run":
        # Zoom: a drag across the first plot narrows its time axis.
        before = page.evaluate("[aiftPlots[0].scales.x.min, aiftPlots[0].scales.x.max]")
        page.locator(".grid").screenshot(path=str(shots / "run_plots.png"))
        over = page.locator("#joint-1 .u-over")
        over.scroll_into_view_if_needed()
        box = over.bounding_box()
        y = box["y"] + box["height"] / 2
        page.mouse.move(box["x"] + box["width"] * 0.3, y)
        page.mouse.down()
        page.mouse.move(box["x"] + box["width"] * 0.6, y, steps=8)
        page.mouse.up()
        after = page.evaluate("[aiftPlots[0].scales.x.min, aiftPlots[0].scales.x.max]")
        assert after[1] - after[0] < 0.5 * (before[1] - before[0]), (before, after)
        assert page.evaluate("aiftPlots.length") >= 6
        assert_distinct_tick_labels(page)
        # A narrow range on the belief-error axis (the default number format printed 0.0012 and
        # 0.0014 both as "0.001"), and a range in 1e-6.
        for lo, hi in [(0.001, 0.0018), (2e-6, 9e-6), (1.0001, 1.0003)]:
            labels = page.evaluate(f"(() => {{ var p = aiftPlots[0]; p.setScale('y', {{min: {lo}, max: {hi}}}); return p.axes[1]._values; }})()")
            shown = [v for v in labels if v]
            assert len(shown) >= 2 and len(set(shown)) == len(shown), (lo, hi, labels)
        assert page.locator("pre").inner_text().startswith("# Resolved by aift")
    if kind == "campaign":
        # Links down to cells resolve to anchors on the page.
        hrefs = page.evaluate("[...document.querySelectorAll('a[href^=\"#cell-\"]')].map(a => a.getAttribute('href'))")
        assert hrefs, "no links to cells"
        for h in hrefs:
            assert page.locator(h).count() == 1, h
    page.close()


def assert_distinct_tick_labels(page):
    """No axis of any zoomable plot on the page shows the same tick label twice."""
    axes = page.evaluate("aiftPlots.flatMap(p => p.axes.map(a => a._values || []))")
    for labels in axes:
        shown = [v for v in labels if v]
        assert len(set(shown)) == len(shown), labels


def test_aift_report_rewrites_the_same_page(folders, aift_bin, tmp_path):
    import subprocess

    for kind in ["table", "campaign"]:
        copy = tmp_path / kind
        shutil.copytree(folders / kind, copy)
        (copy / "report.html").unlink()
        p = subprocess.run([str(aift_bin), "report", copy], capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        assert (copy / "report.html").read_bytes() == (folders / kind / "report.html").read_bytes()
