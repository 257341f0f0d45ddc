"""The viewer in a real browser: headless Chromium (software WebGL) opens the page, the scene renders points,
and moving the time slider with the keyboard changes the frame on the server and what is drawn.

Skips where Chromium, ChromeDriver or selenium are missing (``make test`` installs them where it can)."""

import io
import os
import shutil
import tempfile
import time

import numpy as np
import pytest

from exact_result import exact_result
from test_viz import free_port

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
DRIVER = shutil.which("chromedriver")
pytestmark = pytest.mark.skipif(not (CHROMIUM and DRIVER), reason="chromium and chromedriver not installed")


def _browser(user_dir: str):
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    o = webdriver.ChromeOptions()
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-quic",
              "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
              f"--user-data-dir={user_dir}", "--window-size=1280,800"):
        o.add_argument(a)
    o.binary_location = CHROMIUM
    return webdriver.Chrome(service=Service(DRIVER), options=o)


def _canvas(driver) -> np.ndarray:
    """The 3D area of a screenshot (the left part; the control panel sits on the right), RGB int."""
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB")).astype(int)
    h, w = img.shape[:2]
    return img[int(0.2 * h):int(0.9 * h), int(0.05 * w):int(0.7 * w)]  # below the notices, left of the panel


def _wait(cond, timeout: float, step: float = 0.5):
    end = time.time() + timeout
    while time.time() < end:
        out = cond()
        if out:
            return out
        time.sleep(step)
    return cond()


def test_viewer_renders_and_slider_changes_the_scene():
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    from trackingworld.viz.viewer import Viewer

    res, frames = exact_result()
    v = Viewer(res, frames, port=free_port(), verbose=False)
    user_dir = tempfile.mkdtemp(prefix="tw-chromium-")
    driver = _browser(user_dir)
    try:
        driver.get(f"http://127.0.0.1:{v.port}")

        def drawn():
            c = _canvas(driver)
            ink = (np.abs(c - 255).sum(-1) > 60).mean()  # background is white
            cube = ((c[..., 0] > 170) & (c[..., 1] < 150) & (c[..., 2] < 110)).sum()  # the red-orange mover
            return (ink, cube, c) if ink > 0.03 and cube > 20 else None

        first = _wait(drawn, 90)
        assert first, "the viewer page never showed the point cloud"
        ink0, cube0, c0 = first
        sliders = _wait(lambda: driver.find_elements(By.CSS_SELECTOR, "[role=slider]"), 30)
        assert sliders, "no slider on the page"
        sliders[0].click()  # the first slider is the time slider
        for _ in range(6):
            sliders[0].send_keys(Keys.ARROW_RIGHT)
            time.sleep(0.2)
        assert _wait(lambda: v.t >= 5, 30), f"the server stayed at frame {v.t}"

        def changed():
            c = _canvas(driver)
            diff = np.abs(c - c0).sum(-1) > 60
            return (diff.mean(), c) if diff.mean() > 0.005 else None

        after = _wait(changed, 60)
        assert after, "moving the time slider did not change what is drawn"
        if os.environ.get("TW_BROWSER_SHOTS"):  # to look at what the browser drew: before | after the slider
            from PIL import Image

            Image.fromarray(np.concatenate([c0, after[1]], 1).astype(np.uint8)).save(os.environ["TW_BROWSER_SHOTS"])
    finally:
        driver.quit()
        v.stop()
        shutil.rmtree(user_dir, ignore_errors=True)
