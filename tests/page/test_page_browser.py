"""The set-up page in a real browser: Debian's chromium, headless, driven through its chromedriver
(selenium). A screenshot is taken (kept with a failing test's tmp_path), and a click on a jog
button moves the simulated printer.

With THREEDCAL_PAGE_FIGURE=path the test also saves a screenshot of the page during a simulated
collection there (docs/figures/rig_page.png is made so)."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import pytest
from simulated_rig import call, write_scene

from threedcal.page.control import RigControl
from threedcal.page.server import serving

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
# What the browser may do: nothing but load the page (no first-run, sync, updates or GPU).
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1000,720",
)

HAVE_CHROMIUM = Path(CHROMIUM).is_file() and Path(CHROMEDRIVER).is_file()
# .ci/run sets THREEDCAL_REQUIRE_CHROMIUM where it installed them: there a missing browser fails.
pytestmark = pytest.mark.skipif(
    not HAVE_CHROMIUM and not os.environ.get("THREEDCAL_REQUIRE_CHROMIUM"),
    reason="needs Debian's chromium and chromium-driver (apt-get install chromium chromium-driver; "
    ".ci/run installs them where it runs as root)",
)


@pytest.fixture
def browser(tmp_path):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'chromium-profile'}"):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(30)
    try:
        yield driver
    finally:
        driver.quit()


def wait_for(predicate, timeout_s=30.0, what="the page"):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what() if callable(what) else what}")


@pytest.mark.slow  # chromium's start: seconds
def test_the_page_in_chromium_jogs_the_simulated_printer(tmp_path, monkeypatch, browser):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    monkeypatch.chdir(tmp_path)
    config, scene = write_scene(tmp_path, saved=True)
    with RigControl(config, scene) as control, serving(control) as url:
        browser.get(url)
        title = browser.find_element(By.ID, "title")
        wait_for(lambda: "digit_fots" in title.text, what="the status")
        wait_for(lambda: "connected" in browser.find_element(By.ID, "link").text, what="the socket")
        browser.find_element(By.ID, "home").click()
        wait_for(lambda: control.rig.printer.homed and control.busy is None, what="homing")
        before = control.rig.bench.firmware.position()
        Select(browser.find_element(By.ID, "step")).select_by_visible_text("1")
        browser.find_element(By.CSS_SELECTOR, '#jog button[data-axis="x"][data-sign="1"]').click()
        wait_for(lambda: control.rig.bench.firmware.position()[0] > before[0] + 0.5, what="the jog")
        after = control.rig.bench.firmware.position()
        assert after[0] == pytest.approx(before[0] + 1.0, abs=1e-3)
        assert after[1:] == pytest.approx(before[1:], abs=1e-3)
        # the page shows it, and the camera's image has loaded
        wait_for(lambda: f"{after[0]:.3f}" in browser.find_element(By.ID, "position").text)
        view = browser.find_element(By.ID, "view")
        wait_for(lambda: browser.execute_script("return arguments[0].naturalWidth", view) > 0)
        # a refusal is shown as the server gave it
        browser.find_element(By.CSS_SELECTOR, '#jog button[data-axis="z"][data-sign="-1"]').click()
        wait_for(
            lambda: control.rig.bench.firmware.position()[2] < after[2] - 0.5 and not control.busy,
            what="the jog down",
        )
        Select(browser.find_element(By.ID, "step")).select_by_visible_text("10")
        browser.find_element(By.CSS_SELECTOR, '#jog button[data-axis="z"][data-sign="-1"]').click()
        wait_for(
            lambda: "deepest" in browser.find_element(By.ID, "refusal").text,
            what=lambda: (
                f"the refusal (page: {browser.find_element(By.ID, 'refusal').text!r}, "
                f"{browser.find_element(By.ID, 'message').text!r}; rig: {control.refusal!r})"
            ),
        )
        shot = tmp_path / "page.png"
        assert browser.save_screenshot(str(shot)) and shot.stat().st_size > 10_000
        figure = os.environ.get("THREEDCAL_PAGE_FIGURE")
        if figure:
            _collection_figure(browser, control, url, Path(figure))


def _collection_figure(browser, control, url, path: Path) -> None:
    """The page while a simulated collection runs, after the gel was found and the mount saved
    (the probe drawn over the image), saved to `path`."""
    from selenium.webdriver.common.by import By

    for step in ({"axis": "z", "step_mm": 2.0}, {"axis": "x", "step_mm": -1.5}):
        call(url, "api/jog", step)
    assert call(url, "api/find", {})[0] == 200
    wait_for(lambda: control.busy is None, timeout_s=300, what="finding the gel")
    assert control.found is not None, control.find_state
    # the scene's mount file exists: the page asks before replacing it (the old one is kept)
    browser.find_element(By.ID, "save").click()
    wait_for(lambda: _alert(browser), what="the page's question")
    browser.switch_to.alert.accept()
    wait_for(lambda: control.saved, what="the saved mount")
    assert call(url, "api/collect", {})[0] == 200
    wait_for(  # into the grid's presses, past the touch search and the registration presses
        lambda: control.collection.get("rows_done", 0) > control.collection["rows_total"] - 25,
        timeout_s=300,
        what="the collection's grid",
    )
    view = browser.find_element(By.ID, "view")
    seq = control.frame_seq
    wait_for(lambda: control.frame_seq > seq + 1, what="a new frame")
    wait_for(lambda: browser.execute_script("return arguments[0].complete", view))
    from PIL import Image

    shot = path.with_suffix(".full.png")
    browser.save_screenshot(str(shot))
    image = Image.open(shot).convert("RGB")
    image.convert("P", palette=Image.Palette.ADAPTIVE, colors=256).save(path, optimize=True)
    shot.unlink()
    call(url, "api/stop", {})


def _alert(browser) -> bool:
    from selenium.common.exceptions import NoAlertPresentException

    try:
        return "Replace it?" in browser.switch_to.alert.text
    except NoAlertPresentException:
        return False
