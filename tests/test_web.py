"""membrax serve: the page answers the CLI's numbers and the CLI's words; driven in a real browser.

The browser is Debian's headless Chromium with its chromedriver (``apt-get install chromium
chromium-driver``; ``.ci/run`` installs them), driven by Selenium; nothing is downloaded at run time.
"""

import base64
import io
import shutil
import socket
import threading
import time
import zipfile
from importlib import resources
from pathlib import Path

import pytest

from calibrate import series, web
from membrax import cli

SERIES = resources.files("calibrate") / "data" / "example_series"


def _example_series():
    """The shipped example series: its records and, as the page takes them, the first test's specimen."""
    tests = series.read_series_sheet(Path(str(SERIES)) / "series.toml")
    return [test.record for test in tests], web.form_values(tests[0].specimen)


def _cli_envelopes(records, fields, folder) -> str:
    argv = ["correct", *map(str, records), "--out", str(folder)]
    for name, value in fields.items():
        argv += [f"--{name.replace('_', '-')}", value]
    assert cli.main(argv) == 0
    return (folder / "envelopes.csv").read_text()


def test_the_page_answers_the_cli_s_numbers_and_the_cli_s_words(tmp_path, capsys):
    """Starlette's test client: the example series' envelopes equal `membrax correct`'s, byte for byte; the
    zip holds every file; a bad record and a bad field answer 400 with the CLI's message."""
    from starlette.testclient import TestClient

    records, fields = _example_series()
    expected = _cli_envelopes(records, fields, tmp_path / "cli")
    capsys.readouterr()
    client = TestClient(web.app())
    page = client.get("/")
    assert (
        page.status_code == 200
        and 'id="records"' in page.text
        and "http" not in page.text.split("<script>")[1]
    )
    # the fields in a laboratory's words, no class names of the code
    assert "Specimen diameter after consolidation (mm)" in page.text and "LabSpecimen" not in page.text
    files = [("records", (Path(r).name, Path(r).read_bytes(), "text/csv")) for r in records]
    answer = client.post("/correct", data=fields, files=files)
    assert answer.status_code == 200, answer.text
    data = answer.json()
    assert data["envelopes"] == expected
    with zipfile.ZipFile(io.BytesIO(base64.b64decode(data["archive"]))) as bundle:
        names = sorted(bundle.namelist())
    assert names == sorted(p.name for p in (tmp_path / "cli").iterdir())
    bad = [("records", ("bad.csv", b"axial strain (%),cell pressure (kPa)\n0,25\n", "text/csv"))]
    refused = client.post("/correct", data=fields, files=bad)
    assert refused.status_code == 400
    assert refused.json()["error"].startswith("bad.csv, line 1 (header")
    assert "no column 'volumetric_strain' or 'radial_strain'" in refused.json()["error"]
    wrong = client.post("/correct", data={**fields, "membrane_modulus_kpa": "1.4"}, files=files)
    assert wrong.status_code == 400 and "membrane_modulus_kpa" in wrong.json()["error"]


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture
def server():
    import uvicorn

    port = _free_port()
    instance = uvicorn.Server(uvicorn.Config(web.app(), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=instance.run, daemon=True)
    thread.start()
    started = time.monotonic()
    while not instance.started and time.monotonic() - started < 30:
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}/"
    instance.should_exit = True
    thread.join(timeout=10)


def _browser():
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if chromium is None or driver is None:  # .ci/run installs them; a machine that cannot is told so
        pytest.skip("no chromium/chromedriver on this machine: apt-get install chromium chromium-driver")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu"):
        options.add_argument(flag)
    return webdriver.Chrome(service=Service(driver), options=options)


@pytest.mark.slow
def test_in_a_real_browser_the_example_series_gives_the_cli_s_envelopes(server, tmp_path, capsys):
    """Headless Chromium: upload the example series, read the envelope table (equal to the CLI's), see the
    figure drawn, then upload a bad file and read the CLI's message on the page."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions
    from selenium.webdriver.support.ui import WebDriverWait

    records, fields = _example_series()
    expected = _cli_envelopes(records, fields, tmp_path / "cli")
    capsys.readouterr()
    browser = _browser()
    try:
        browser.get(server)
        wait = WebDriverWait(browser, 300)
        browser.find_element(By.ID, "records").send_keys("\n".join(str(Path(r).resolve()) for r in records))
        for name, value in fields.items():
            browser.find_element(By.ID, name).send_keys(value)
        browser.find_element(By.ID, "submit").click()
        wait.until(expected_conditions.visibility_of_element_located((By.ID, "results")))
        rows = browser.find_elements(By.CSS_SELECTOR, "#envelopes tr")
        shown = [[cell.text for cell in row.find_elements(By.CSS_SELECTOR, "th, td")] for row in rows]
        assert shown == [line.split(",") for line in expected.strip().splitlines()]
        width = browser.execute_script("return document.getElementById('figure').naturalWidth")
        assert width > 500  # the PNG decoded and drawn
        bad = tmp_path / "bad.csv"
        bad.write_text("axial strain (%),cell pressure (kPa)\n0,25\n")
        browser.find_element(By.ID, "records").clear()
        browser.find_element(By.ID, "records").send_keys(str(bad))
        browser.find_element(By.ID, "submit").click()
        wait.until(lambda b: b.find_element(By.ID, "error").text)
        message = browser.find_element(By.ID, "error").text
        assert message.startswith("bad.csv, line 1 (header") and "no column 'volumetric_strain'" in message
    finally:
        browser.quit()
