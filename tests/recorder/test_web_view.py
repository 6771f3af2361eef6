"""The live view without a display: `spikinglab run --view` serves the Rerun web viewer, and headless
Chromium (Debian's, driven by playwright) renders the running insect's world from it."""

from __future__ import annotations

import io
import os
import shutil
import signal
import time

import numpy as np
from PIL import Image
from playwright.sync_api import sync_playwright

from services.recorder.recorder import PATCH_COLOURS

from ..processes import live_run, running_with

CHROMIUM_ARGS = ["--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"]  # software WebGL


def pixels_of(png: bytes, rgb: tuple, tolerance: int = 12) -> int:
    image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    return int((np.abs(image - np.array(rgb)).max(axis=2) <= tolerance).sum())


def test_run_view_serves_a_web_viewer_that_renders_the_run(tmp_path):
    chromium = shutil.which("chromium")
    assert chromium, "Debian's chromium is needed (scripts/test.sh installs it: apt-get install chromium)"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    run, said = live_run(tmp_path, "live", env)
    try:
        url = said.split("open ", 1)[1].split()[0]
        assert url.startswith("http://127.0.0.1:")
        colours = {name: rgb for _, name, rgb in PATCH_COLOURS if name in ("wall", "predator", "food")}
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1400, "height": 800})
            page.goto(url + "&renderer=webgl")
            deadline, found = time.monotonic() + 120, {}
            while time.monotonic() < deadline:  # the wasm viewer needs real time to load and draw
                time.sleep(3)
                shot = page.screenshot(timeout=60_000)  # software WebGL on a loaded machine is slow
                found = {name: pixels_of(shot, rgb) for name, rgb in colours.items()}
                if min(found.values()) > 500:
                    break
            title = page.title()
            (tmp_path / "web_view.png").write_bytes(shot)
            browser.close()
        assert title == "Rerun Viewer"
        # the map of the run, drawn from the served data: walls, predators and food in their colours
        logs = "\n".join(f"--- {log.name}\n{log.read_text()[-1500:]}" for log in (tmp_path / "live").glob("*.log"))
        assert min(found.values()) > 500, (
            f"pixels of each map colour: {found} (screenshot: {tmp_path}/web_view.png)\n{logs}"
        )
        assert pixels_of(shot, (0, 0, 0), tolerance=0) < 0.9 * 1400 * 800  # not a blank page
    finally:
        run.send_signal(signal.SIGINT)  # the run ends at its ticks done, with viewer servers and services
        run.communicate(timeout=120)
    assert run.returncode == 130
    assert (tmp_path / "live" / "recording.rrd").stat().st_size > 0
    assert not running_with(str(tmp_path))
