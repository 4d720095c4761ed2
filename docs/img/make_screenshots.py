"""Screenshots of the web station's pages for docs/web.md: docs/img/web-runs.png, web-run.png,
web-live.png, web-start.png.

    python docs/img/make_screenshots.py

Starts `bench serve` on a free port of 127.0.0.1 with a temporary runs directory, fills it with a
few runs (dry-runs of the library and recorder-written files), drives Debian's chromium with
Playwright and saves one PNG per page. Look at each one before committing it.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tests.browser import TOKEN, Server, launch_browser, make_run_file  # noqa: E402

OUT = ROOT / "docs" / "img"


def _dry_run(runs: Path, procedure: str, *args: str) -> None:
    subprocess.run([sys.executable, "-m", "bench", "run", procedure, "--config", "configs/sim.yaml", "--sim", "--runs-dir", str(runs),
                    "--answers", "procedures/answers/ci.yaml", *args], cwd=ROOT, capture_output=True, timeout=600)


def _until(page, cond, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not cond():
        page.wait_for_timeout(200)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        runs = Path(tmp) / "runs"
        _dry_run(runs, "procedures/startup_profile.yaml", "--unit", "SN0042")
        _dry_run(runs, "tests/data/procedures/web_prompt.yaml", "--unit", "SN0043", "-p", "hold=20 s")
        make_run_file(runs, rows=200_000, unit="SN0017", procedure="long_soak", rate_hz=100.0)
        make_run_file(runs, rows=5_000, unit="SN0042", procedure="functional_test", status="aborted", abort_reason="operator stop")
        server = Server(runs, "--procedures", str(ROOT / "tests" / "data" / "procedures"), "--config", str(ROOT / "configs" / "sim.yaml"))
        try:
            for browser in launch_browser():
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                page.goto(server.url)
                page.wait_for_selector("#runs-table")
                page.screenshot(path=str(OUT / "web-runs.png"))

                page.click("tr.run-row >> text=startup_profile")
                page.wait_for_selector("#verdict-word")
                _until(page, lambda: page.locator("canvas[data-updates='1']").count() >= 3)
                page.screenshot(path=str(OUT / "web-run.png"), full_page=False)
                page.locator("#plots").scroll_into_view_if_needed()
                page.mouse.move(5, 5)
                page.mouse.wheel(0, 700)  # over the header, not a plot (the wheel zooms plots)
                page.wait_for_timeout(500)
                page.screenshot(path=str(OUT / "web-run-plots.png"), full_page=False)

                page.goto(server.url + "start?procedure=web_prompt.yaml")
                page.fill("#token-input", TOKEN)
                page.click("#token-save")
                page.fill(".s-param[data-name=hold]", "10 min")
                page.fill("#s-unit", "SN0044")
                page.click("#s-plan")
                _until(page, lambda: "long recording" in page.inner_text("#s-plan-text"))
                page.click("#s-start")
                page.wait_for_selector("a.started-run")
                page.wait_for_timeout(1500)
                page.screenshot(path=str(OUT / "web-start.png"), full_page=True)

                page.click("a.started-run")
                page.wait_for_selector("#prompt .question", timeout=30_000)
                page.wait_for_timeout(3000)
                page.screenshot(path=str(OUT / "web-live.png"), full_page=False)
                page.click("#stop-btn")
                _until(page, lambda: "aborted" in page.inner_text("#run-status"))
                page.close()
        finally:
            server.stop()
    print("wrote", ", ".join(f"docs/img/web-{n}.png" for n in ("runs", "run", "start", "live")))


if __name__ == "__main__":
    main()
