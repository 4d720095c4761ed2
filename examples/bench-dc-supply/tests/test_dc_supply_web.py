"""The supply on the web station's live page (`bench serve`), in a real browser (tests/browser.py:
Debian's chromium driven by Playwright; skipped with the reason where either is missing): its
readings plotted as they come, its limits shown, like any instrument's."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.browser import TOKEN, Server, launch_browser, until

HERE = Path(__file__).resolve().parents[1]
CONFIG = HERE / "configs" / "board_on_supply.yaml"


def _rows(page, selector: str) -> int:
    v = page.get_attribute(selector, "data-rows")
    return int(v) if v else 0


@pytest.fixture(scope="module")
def browser():
    yield from launch_browser()


def test_the_live_page_plots_the_supply_and_shows_its_limits(browser, tmp_path):
    library = tmp_path / "procedures"
    library.mkdir()
    (library / "power_and_wait.yaml").write_text(
        (HERE / "procedures" / "unit_power_on.yaml").read_text()
        .replace("name: unit_power_on", "name: power_and_wait")
        .replace("  - wait: 2 s\n", "  - wait: 0.2 s\n")  # web dry-runs: wall clock, and nothing here looks at the wait
        .replace("  - record: {instrument: imu, duration: 60 s, window: powered, name: running}",
                 "  - prompt: {id: look, text: \"Supply readings on the page?\"}\n"
                 "  - record: {instrument: imu, duration: 3 s, window: powered, name: running}"))  # web dry-runs: wall clock
    server = Server(tmp_path / "runs", "--procedures", str(library), "--config", str(CONFIG))
    try:
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.set_default_timeout(20_000)
        page.goto(server.url + "start")
        page.fill("#token-input", TOKEN)
        page.click("#token-save")
        page.wait_for_selector("#token-state.ok")
        page.select_option("#s-procedure", "power_and_wait.yaml")
        page.fill("#s-operator", "ana")
        page.click("#s-start")
        page.click("a.started-run")
        page.wait_for_selector("#prompt .question", timeout=30_000)
        current = "canvas[data-key='psu/monitor'][data-column=current1]"
        r0 = until(page, lambda: _rows(page, current), "the supply's current rows")
        until(page, lambda: _rows(page, current) > r0, "a plot update of the supply's current")
        limits = page.locator("#limits-table").inner_text()
        assert "psu voltage" in limits and "5.25 V" in limits and "checked" in limits, limits
        page.click("#answer-yes")
        page.wait_for_selector("#verdict-word", state="attached", timeout=60_000)
        page.close()
    finally:
        err = server.stop()
    assert "Traceback" not in err, err
