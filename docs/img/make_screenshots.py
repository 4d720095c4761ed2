"""Screenshots of the web station's pages for docs/web.md: docs/img/web-runs.png (and -1024),
web-run.png, web-run-plots.png, web-start.png, web-prompt.png, web-live.png (and -1024),
web-unit.png.

    python docs/img/make_screenshots.py

Starts `bench serve` on a free port of 127.0.0.1 with a temporary runs directory: several units of
two part numbers with dry-runs mixed in (tests/unit_runs.py, which says what of it stands in for
hardware runs) and a dry-run of the thermal ramp; then starts the live run of
tests/data/procedures/web_live.yaml from the page, drives Debian's chromium with Playwright at 1400
px and at 1024x768 and saves one PNG per view. Look at each one before committing it.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tests.browser import TOKEN, Server, launch_browser  # noqa: E402
from tests.unit_runs import build_runs  # noqa: E402

OUT = ROOT / "docs" / "img"
WIDE, NARROW = {"width": 1400, "height": 900}, {"width": 1024, "height": 768}


def _until(page, cond, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not cond():
        page.wait_for_timeout(200)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        runs = build_runs(Path(tmp))
        subprocess.run([sys.executable, "-m", "bench", "run", "procedures/thermal_ramp_ambient.yaml", "--config", "configs/sim.yaml",
                        "--sim", "--runs-dir", str(runs), "--answers", "procedures/answers/ci.yaml", "--unit", "SN14", "--part", "PN-100"],
                       cwd=ROOT, capture_output=True, timeout=900, check=True)
        server = Server(runs, "--procedures", str(ROOT / "tests" / "data" / "procedures"), "--config", str(ROOT / "configs" / "sim.yaml"))
        try:
            for browser in launch_browser():
                page = browser.new_page(viewport=WIDE)
                page.goto(server.url)
                page.wait_for_selector("#runs-table")
                page.screenshot(path=str(OUT / "web-runs.png"))
                page.set_viewport_size(NARROW)
                page.wait_for_timeout(300)
                page.screenshot(path=str(OUT / "web-runs-1024.png"))
                page.set_viewport_size(WIDE)

                page.goto(server.url + "unit?serial=SN12")
                page.wait_for_selector("#figures .figure")
                page.wait_for_timeout(500)
                page.screenshot(path=str(OUT / "web-unit.png"), full_page=True)

                page.goto(server.url + "?procedure=thermal_ramp_ambient")
                page.wait_for_selector("tr.run-row a.run-link")
                page.click("tr.run-row a.run-link")
                page.wait_for_selector("#verdict-word")
                _until(page, lambda: page.locator("canvas[data-updates='1']").count() >= 3)
                page.screenshot(path=str(OUT / "web-run.png"), full_page=False)
                top = page.locator("h2", has_text="Streams").bounding_box()["y"]
                page.screenshot(path=str(OUT / "web-run-plots.png"), full_page=True,
                                clip={"x": 0, "y": top - 8, "width": WIDE["width"], "height": WIDE["height"]})

                page.goto(server.url + "start?procedure=web_live.yaml")
                page.fill("#name-input", "alice")
                page.fill("#token-input", TOKEN)
                page.click("#token-save")
                page.wait_for_selector("#s-params .param-row")
                page.fill("#s-operator", "alice")
                page.fill("#s-unit", "SN15")
                page.click("#s-plan")
                _until(page, lambda: "long recording" in page.inner_text("#s-plan-text"))
                page.uncheck("#s-realtime")
                page.click("#s-start")
                page.wait_for_selector("a.started-run")
                page.wait_for_timeout(1500)
                page.screenshot(path=str(OUT / "web-start.png"), full_page=True)

                page.click("a.started-run")
                page.wait_for_selector("#prompt .question", timeout=30_000)
                page.fill("#answer-text", "yse")
                page.click("#answer-send")
                _until(page, lambda: "not an accepted answer" in page.inner_text("#prompt-error"))
                page.click("#answer-no")
                page.wait_for_selector("#no-confirm-box")
                page.screenshot(path=str(OUT / "web-prompt.png"), full_page=False)
                page.click("#no-confirm-box-cancel")
                page.click("#answer-yes")
                page.wait_for_selector("#prompt", state="detached")
                _until(page, lambda: page.locator("canvas[data-time-axis=hms]").count() > 0)
                page.click("#pause-btn")
                _until(page, lambda: "paused" in page.inner_text("#run-status"))
                page.wait_for_timeout(2500)
                page.screenshot(path=str(OUT / "web-live.png"), full_page=False)
                page.set_viewport_size(NARROW)
                page.wait_for_timeout(1500)
                page.screenshot(path=str(OUT / "web-live-1024.png"), full_page=False)
                page.click("#stop-btn")
                page.click("#stop-confirm-box-ok")
                _until(page, lambda: "aborted" in page.inner_text("#run-status"))
                page.close()
        finally:
            server.stop()
    print("wrote", ", ".join(f"docs/img/web-{n}.png" for n in ("runs", "runs-1024", "unit", "run", "run-plots", "start", "prompt",
                                                               "live", "live-1024")))


if __name__ == "__main__":
    main()
