"""The viewer in a real browser: headless Chromium from the system's packages, driven by Selenium (the ``view``
extra). Skips with one line where no browser is installed.

Opens the side-by-side view of the shipped sample and its input raster, zooms to 100x (100 screen pixels per input
pixel) on the triangle's edge and reads both viewers' canvases along a column across the edge: the file's edge
crosses from one side's value to the other's within 2 screen pixels, the bicubic raster's over many. With
``DFC_VIEWER_SCREENSHOT=PATH`` it also saves a screenshot of the page there (``docs/images/viewer_100x.png``)."""

import os
import re
import shutil
import time

import numpy as np
import pytest

CHROMIUM = next((p for p in ("/usr/bin/chromium", shutil.which("chromium") or "") if p and os.path.exists(p)), None)
CHROMEDRIVER = next((p for p in ("/usr/bin/chromedriver", shutil.which("chromedriver") or "")
                     if p and os.path.exists(p)), None)
webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (pip install 'dfc[view]')")
if CHROMIUM is None or CHROMEDRIVER is None:
    pytest.skip("no Chromium and chromedriver installed (apt-get install chromium chromium-driver)",
                allow_module_level=True)

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--window-size=1400,760", "--force-device-scale-factor=1"]
EDGE = (190.0, 45.0)  # on the triangle's edge from (150, 30) to (230, 60)
ZOOM = 100.0


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in FLAGS + [f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}"]:
        options.add_argument(flag)
    driver = webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))
    driver.set_script_timeout(30)
    yield driver
    driver.quit()


def wait_for(driver, script: str, timeout: float = 90.0):
    deadline = time.monotonic() + timeout
    while not driver.execute_script(script):
        assert time.monotonic() < deadline, f"timed out waiting for: {script}"
        time.sleep(0.1)


def open_at(driver, url: str, zoom: float, centre) -> None:
    """Load the viewer's side-by-side page at ``url``, zoom both viewers to ``zoom`` at the domain point ``centre``
    and wait until every tile in view has been drawn."""
    driver.get(url + "?compare=1")
    wait_for(driver, "const s = window.dfcViewer; return !!(s && s.left && s.right && s.left.world.getItemCount()"
                     " && s.right.world.getItemCount())")
    driver.execute_script("window.dfcViewer.zoomTo(arguments[0], arguments[1], arguments[2])", zoom, *centre)
    time.sleep(0.5)
    wait_for(driver, "return window.dfcViewer.fullyLoaded()")
    time.sleep(0.5)  # the last tiles' draw


def column(driver, which: str, half: int) -> np.ndarray:
    """(2·half, 4) uint8 RGBA of the drawer canvas of viewer ``which`` along its centre column, centre ± half."""
    data = driver.execute_script("""
        const c = window.dfcViewer[arguments[0]].drawer.canvas, h = arguments[1];
        const x = Math.floor(c.width / 2), y = Math.floor(c.height / 2);
        return Array.from(c.getContext('2d').getImageData(x, y - h, 1, 2 * h).data);""", which, half)
    return np.array(data, dtype=np.uint8).reshape(-1, 4)


def crossing_width(values: np.ndarray, a: float, b: float) -> int:
    """Pixels strictly between 10 % and 90 % of the way from ``a`` to ``b``."""
    t = (values - a) / (b - a)
    return int(np.sum((t > 0.1) & (t < 0.9)))


def test_viewer_keeps_the_edge_sharp_at_100x(server, browser):
    host, port, _ = server
    open_at(browser, f"http://{host}:{port}/", ZOOM, EDGE)
    assert browser.find_element("id", "zoom").text == "100×"
    assert browser.find_element("id", "barlabel").text == "1 input px"
    assert browser.execute_script("return document.getElementById('bar').style.width") == "100px"

    field = column(browser, "left", 40)[:, :3].astype(float)
    c = int(np.argmax(np.ptp(field, axis=0)))  # the channel with the largest jump
    a, b = np.median(field[:10, c]), np.median(field[-10:, c])
    assert abs(b - a) > 40, field[:, c]  # the column crosses the edge
    assert crossing_width(field[:, c], a, b) <= 2, field[:, c]

    raster = column(browser, "right", 150)[:, c].astype(float)
    assert crossing_width(raster, a, b) >= 20, raster  # the input raster, upsampled: a blur ~1 input pixel wide

    from selenium.webdriver import ActionChains

    ActionChains(browser).move_to_element(browser.find_element("id", "left")).perform()
    wait_for(browser, "return document.getElementById('readout').textContent.startsWith('x ')", 30)
    x, y = (float(v) for v in re.match(r"x (\S+)\s+y (\S+)", browser.find_element("id", "readout").text).groups())
    assert abs(x - EDGE[0]) < 0.05 and abs(y - EDGE[1]) < 0.05  # the cursor's domain point: the centre, ±5 px

    overlay = ("const c = document.getElementById('overlay');"
               "const alpha = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
               "return Array.from(alpha.filter((_, k) => k % 4 == 3))")
    assert max(browser.execute_script(overlay)) == 0  # the curves overlay is off
    browser.find_element("id", "curves").click()
    painted = np.array(browser.execute_script(overlay))
    assert 0 < np.count_nonzero(painted) < painted.size // 20  # on: the edge drawn as a thin line
    browser.find_element("id", "curves").click()

    target = os.environ.get("DFC_VIEWER_SCREENSHOT")
    if target:
        browser.save_screenshot(target)


def test_showing_the_input_raster_keeps_the_zoom(server, browser):
    """Toggling the side-by-side view resizes the dfc pane; the zoom (screen pixels per input pixel) and the centre
    stay, whenever the browser gets to the resize (before the viewer's zoom or after it)."""
    host, port, _ = server
    open_at(browser, f"http://{host}:{port}/", ZOOM, EDGE)
    settled = ("const v = window.dfcViewer.left;"
               "return v.viewport.getContainerSize().x === v.container.clientWidth")
    width = browser.execute_script("return window.dfcViewer.left.container.clientWidth")
    for checked in (False, True):
        browser.find_element("id", "compare").click()
        assert browser.find_element("id", "compare").is_selected() == checked
        wait_for(browser, f"return window.dfcViewer.left.container.clientWidth {'>' if not checked else '=='} {width}",
                 30)
        wait_for(browser, settled, 30)
        time.sleep(0.2)  # the resize's redraw
        assert browser.find_element("id", "zoom").text == "100×"
        centre = browser.execute_script(
            "const v = window.dfcViewer.left.viewport;"
            "const p = v.viewportToImageCoordinates(v.getCenter(true)); return [p.x, p.y]")
        grid = browser.execute_script("const [x, y] = arguments; const f = window.dfcViewer.file;"
                                      "return [(x - f.domain[0]) * f.width / (f.domain[2] - f.domain[0]),"
                                      " (y - f.domain[1]) * f.height / (f.domain[3] - f.domain[1])]", *EDGE)
        assert np.allclose(centre, grid, atol=0.05 * browser.execute_script("return window.dfcViewer.file.scale"))
    wait_for(browser, "return window.dfcViewer.fullyLoaded()")
    views = browser.execute_script("return ['left', 'right'].map((k) => { const v = window.dfcViewer[k].viewport;"
                                   " const c = v.getCenter(true); return [v.getZoom(true), c.x, c.y]; })")
    assert np.allclose(views[0], views[1], rtol=1e-6, atol=1e-9)  # the raster's viewer, opened again, follows

