"""A local web page for correcting tests: ``membrax serve``.

Contract. :func:`app` returns a Starlette application with two routes: ``GET /`` serves one page of plain
HTML and JavaScript (no script or style from elsewhere), and ``POST /correct`` takes a form with one or more
records (``records``, CSV or .xlsx) and the specimen's fields in the CLI's units and names
(``specimen_diameter_mm``, ``particle_size_mm``, ``membrane_thickness_mm``, ``membrane_modulus_kpa``,
optional ``void_ratio`` and ``specimen_height_mm``), checked by the same code as ``membrax correct``
(:meth:`calibrate.correct.LabSpecimen.from_mm_kpa`, :func:`calibrate.lab.read_lab_record`). It corrects
them as a series (:func:`calibrate.series.correct_series`; one record is a series of one) and answers JSON:
the
envelopes' and tests' tables (the CSVs of :func:`calibrate.series.write_series`), the warnings, the figure
(PNG, base64), the report (HTML) and a zip of every file written, for the page to offer as downloads. A
bad file or field answers status 400 with the CLI's message (``{"error": ...}``), never a traceback.

Nothing leaves the machine: :func:`serve` binds to 127.0.0.1 only, and each request's files are written to
a temporary folder that is removed before the answer is sent. Starlette (with uvicorn, its ASGI server) is
used because it is small and well kept, serves a form and JSON without a template engine, and its test
client needs no server; the page itself needs no framework.
"""

from __future__ import annotations

import base64
import io
import tempfile
import zipfile
from pathlib import Path

from calibrate import correct, series

__all__ = ["PAGE", "app", "form_values", "serve"]

#: The form's specimen fields: (name, label, required).
FIELDS = (
    ("specimen_diameter_mm", "Specimen diameter after consolidation (mm)", True),
    ("particle_size_mm", "Particle size d50 (mm)", True),
    ("membrane_thickness_mm", "Membrane thickness (mm)", True),
    ("membrane_modulus_kpa", "Membrane Young's modulus (kPa; latex ≈ 1400)", True),
    ("void_ratio", "Void ratio e (optional)", False),
    ("specimen_height_mm", "Specimen height after consolidation (mm, optional)", False),
)


def form_values(specimen) -> dict[str, str]:
    """The required fields of :data:`FIELDS` as the page takes them (mm, kPa) of a ``LabSpecimen``."""
    return {
        "specimen_diameter_mm": f"{1e3 * specimen.specimen_diameter:g}",
        "particle_size_mm": f"{1e3 * specimen.particle_diameter:g}",
        "membrane_thickness_mm": f"{1e3 * specimen.membrane_thickness:g}",
        "membrane_modulus_kpa": f"{1e-3 * specimen.membrane_modulus:g}",
    }


_INPUTS = "\n".join(
    f'<label>{label} <input name="{name}" id="{name}" inputmode="decimal"{" required" if needed else ""}>'
    "</label>"
    for name, label, needed in FIELDS
)

#: The page: a form, then the results (filled by the script from the JSON answer).
PAGE = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>membrax: membrane corrections</title>
<style>
body {{ font-family: sans-serif; max-width: 1100px; margin: 1em auto; font-size: 14px; }}
label {{ display: block; margin: 4px 0; }} input {{ margin-left: 6px; }}
table {{ border-collapse: collapse; font-size: 12px; margin: 6px 0; }}
td, th {{ border: 1px solid #bbb; padding: 2px 5px; }} #error {{ color: #b00; white-space: pre-wrap; }}
img {{ max-width: 100%; }}
</style></head><body>
<h1>Membrane corrections of a drained triaxial test series</h1>
<p>Drop one or more records (CSV or .xlsx; columns axial_strain, volumetric_strain or radial_strain,
deviator_stress or axial_stress, cell_pressure, each with its unit, e.g. <code>Axial strain (%)</code>;
compression positive) and give the specimen. Everything runs on this computer; the files are removed
after each answer.</p>
<form id="form">
<label>Records <input type="file" id="records" name="records" multiple required></label>
{_INPUTS}
<button type="submit" id="submit">Correct</button> <span id="status"></span>
</form>
<div id="error"></div>
<div id="results" hidden>
<h2>Envelopes by method</h2><div id="envelopes"></div>
<h2>Tests</h2><div id="tests"></div>
<img id="figure" alt="stress-strain curves and envelopes">
<h2>Warnings</h2><ul id="warnings"></ul>
<p><a id="report" download="series.html">the report (HTML, prints to one page)</a> ·
<a id="archive" download="membrax_corrections.zip">every file (zip: corrected CSVs, tables, figure)</a></p>
</div>
<script>
function table(csv) {{
  const rows = csv.trim().split("\\n").map(line => line.split(","));
  const head = "<tr>" + rows[0].map(c => "<th>" + c + "</th>").join("") + "</tr>";
  const cell = c => "<td>" + c.replaceAll('"', "") + "</td>";
  const body = rows.slice(1).map(r => "<tr>" + r.map(cell).join("") + "</tr>");
  return "<table>" + head + body.join("") + "</table>";
}}
document.getElementById("form").addEventListener("submit", async (event) => {{
  event.preventDefault();
  const status = document.getElementById("status"), error = document.getElementById("error");
  error.textContent = ""; status.textContent = "correcting…";
  document.getElementById("results").hidden = true;
  const answer = await fetch("correct", {{method: "POST", body: new FormData(event.target)}});
  const data = await answer.json();
  status.textContent = "";
  if (!answer.ok) {{ error.textContent = data.error; return; }}
  document.getElementById("envelopes").innerHTML = table(data.envelopes);
  document.getElementById("tests").innerHTML = table(data.tests);
  document.getElementById("figure").src = "data:image/png;base64," + data.figure;
  const list = document.getElementById("warnings");
  list.innerHTML = "";
  for (const text of (data.warnings.length ? data.warnings : ["none"])) {{
    const item = document.createElement("li"); item.textContent = text; list.appendChild(item);
  }}
  const link = (id, parts, type) => {{
    document.getElementById(id).href = URL.createObjectURL(new Blob(parts, {{type: type}}));
  }};
  link("report", [data.report], "text/html");
  link("archive", [Uint8Array.from(atob(data.archive), c => c.charCodeAt(0))], "application/zip");
  document.getElementById("results").hidden = false;
}});
</script>
</body></html>
"""


def _number(form, name: str, required: bool):
    text = str(form.get(name) or "").strip().replace(",", ".")
    if not text:
        if required:
            raise ValueError(
                f"{name}: give a value (the same as membrax correct's --{name.replace('_', '-')})."
            )
        return None
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{name} = {text!r} is not a number; give e.g. 150.") from None


async def _correct(request):
    from starlette.responses import JSONResponse

    form = await request.form()
    uploads = [item for item in form.getlist("records") if getattr(item, "filename", "")]
    with tempfile.TemporaryDirectory(prefix="membrax_serve_") as folder:
        records = Path(folder) / "records"
        try:
            answer = await _answer(form, uploads, records, Path(folder) / "out")
        except (ValueError, FileNotFoundError) as error:  # lab.LabRecordError is a ValueError
            # The temporary path means nothing to the user: name each file as they chose it.
            message = str(error).replace(f"{records}/", "").replace(str(records), "the uploaded files")
            return JSONResponse({"error": message}, status_code=400)
    return JSONResponse(answer)


async def _answer(form, uploads, records: Path, out: Path) -> dict:
    """Correct the uploaded records as a series; the JSON answer (module docstring)."""
    if not uploads:
        raise ValueError("no record: choose one or more CSV or .xlsx files.")
    values = [_number(form, name, needed) for name, _, needed in FIELDS]
    specimen = correct.LabSpecimen.from_mm_kpa(
        *values[:4], void_ratio=values[4], specimen_height_mm=values[5]
    )
    records.mkdir()
    paths = []
    for upload in uploads:
        path = records / (Path(upload.filename).name or "record.csv")
        path.write_bytes(await upload.read())
        paths.append(path)
    result = series.correct_series(series.series_of_files(paths, specimen))
    written = series.write_series(result, out)
    archive = io.BytesIO()
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as bundle:
        for file in sorted(out.iterdir()):
            bundle.write(file, file.name)
    return {
        "envelopes": written["envelopes"].read_text(),
        "tests": written["tests"].read_text(),
        "figure": base64.b64encode(written["figure"].read_bytes()).decode(),
        "report": written["report"].read_text(),
        "archive": base64.b64encode(archive.getvalue()).decode(),
        "warnings": [
            f"{test.name}: {message}"
            for test, corrected in zip(result.tests, result.corrected, strict=True)
            for message in corrected.warnings
        ],
    }


async def _page(request):
    from starlette.responses import HTMLResponse

    return HTMLResponse(PAGE)


def app():
    """The Starlette application of the page (module docstring)."""
    from starlette.applications import Starlette
    from starlette.routing import Route

    return Starlette(routes=[Route("/", _page), Route("/correct", _correct, methods=["POST"])])


def serve(port: int = 8765, open_browser: bool = True) -> None:
    """Serve the page on http://127.0.0.1:``port`` until Ctrl-C; localhost only: nothing leaves here."""
    import threading
    import webbrowser

    import uvicorn

    address = f"http://127.0.0.1:{port}/"
    print(f"membrax: the page is at {address} (Ctrl-C to stop)", flush=True)
    if open_browser:
        threading.Timer(1.0, webbrowser.open, args=(address,)).start()
    uvicorn.run(app(), host="127.0.0.1", port=port, log_level="warning")
