"""The README's picture of ``membrax serve``: the page with the shipped example series corrected.

Starts the page (:mod:`calibrate.web`) on a free local port, drives Debian's headless Chromium with its
chromedriver (``apt-get install chromium chromium-driver``) through Selenium as ``tests/test_web.py`` does,
uploads ``calibrate/data/example_series``'s records with the specimen's sizes, waits for the envelopes and the
figure, and saves the window as a PNG (``docs/serve_page.png`` by default).

Run: ``python examples/serve_screenshot.py [out.png]``; about 30 s on 2 CPU cores.
"""

import shutil
import socket
import sys
import threading
import time
from importlib import resources
from pathlib import Path

import uvicorn
from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support import expected_conditions
from selenium.webdriver.support.ui import WebDriverWait

from calibrate import series, web

out = (
    Path(sys.argv[1])
    if len(sys.argv) > 1
    else Path(__file__).resolve().parents[1] / "docs" / "serve_page.png"
)
sheet = Path(str(resources.files("calibrate") / "data" / "example_series")) / "series.toml"
tests = series.read_series_sheet(sheet)
fields = web.form_values(tests[0].specimen)
with socket.socket() as probe:
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
server = uvicorn.Server(uvicorn.Config(web.app(), host="127.0.0.1", port=port, log_level="warning"))
threading.Thread(target=server.run, daemon=True).start()
while not server.started:
    time.sleep(0.05)
chromium, driver = shutil.which("chromium") or shutil.which("chromium-browser"), shutil.which("chromedriver")
if chromium is None or driver is None:
    raise SystemExit("no chromium/chromedriver on this machine: apt-get install chromium chromium-driver")
options = webdriver.ChromeOptions()
options.binary_location = chromium
for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1280,1700"):
    options.add_argument(flag)
browser = webdriver.Chrome(service=Service(driver), options=options)
try:
    browser.get(f"http://127.0.0.1:{port}/")
    browser.find_element(By.ID, "records").send_keys("\n".join(str(Path(t.record).resolve()) for t in tests))
    for name, value in fields.items():
        browser.find_element(By.ID, name).send_keys(value)
    browser.find_element(By.ID, "submit").click()
    WebDriverWait(browser, 300).until(expected_conditions.visibility_of_element_located((By.ID, "results")))
    browser.save_screenshot(str(out))
finally:
    browser.quit()
    server.should_exit = True
print(f"written {out}")
