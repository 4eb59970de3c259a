"""calibrate.lab: laboratory records read in SI units, and every bad file refused naming line, column, fix."""

import math
import re

import numpy as np
import pytest

from calibrate.lab import LabRecordError, read_lab_record
from membrax import theory

GOOD = """# synthetic: produced by a membrax simulation
# specimen 150 mm
axial_strain [%],volumetric_strain [-],deviator_stress [kPa],cell_pressure [kPa],internal_axial_stress [kPa]
0.0,0.0,0.0,10,10.5
0.5,0.002,20.0,10,31.0
1.0,0.003,30.5,10,41.2
"""


def _write(tmp_path, text, name="lab.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_a_good_record_comes_back_in_si_units(tmp_path):
    record = read_lab_record(_write(tmp_path, GOOD))
    np.testing.assert_allclose(record.axial_strain, [0.0, 0.005, 0.01], rtol=1e-15)
    np.testing.assert_allclose(record.volumetric_strain, [0.0, 0.002, 0.003], rtol=1e-15)
    # σ1 = σ3 + q, in Pa
    np.testing.assert_allclose(record.axial_stress, [1e4, 3e4, 4.05e4], rtol=1e-15)
    np.testing.assert_allclose(record.cell_pressure, 1e4, rtol=1e-15)
    # the right cylinder's radial strain, by theory.radial_strain (ε_a = 1 %, ε_v = 0.3 %)
    assert record.radial_strain[2] == pytest.approx(float(theory.radial_strain(0.01, 0.003)), rel=1e-12)
    assert record.radial_strain[2] == pytest.approx(1 - math.sqrt(0.997 / 0.99), rel=1e-12)
    assert record.comments[0].startswith("synthetic")


def test_radial_strain_and_axial_stress_columns_are_the_same_record(tmp_path):
    first = read_lab_record(_write(tmp_path, GOOD))
    lines = ["axial_strain [-],radial_strain [-],axial_stress [MPa],cell_pressure [Pa]"]
    for ea, er, s1, s3 in zip(
        first.axial_strain, first.radial_strain, first.axial_stress, first.cell_pressure, strict=True
    ):
        lines.append(f"{float(ea)!r},{float(er)!r},{float(s1) / 1e6!r},{float(s3)!r}")
    second = read_lab_record(_write(tmp_path, "\n".join(lines) + "\n", "second.csv"))
    np.testing.assert_allclose(second.volumetric_strain, first.volumetric_strain, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(second.axial_stress, first.axial_stress, rtol=1e-15)


BAD_FILES = [
    # a missing column
    (
        GOOD.replace(",cell_pressure [kPa]", ",confining [kPa]"),
        r"line 3 \(header .*\): no column 'cell_pressure'",
    ),
    # an unknown unit, and a unit left out
    (
        GOOD.replace("deviator_stress [kPa]", "deviator_stress [psi]"),
        r"line 3 \(header .*column 3 \('deviator_stress \[psi\]'\): unknown unit 'psi'.*kPa",
    ),
    (
        GOOD.replace("cell_pressure [kPa]", "cell_pressure"),
        r"column 4 \('cell_pressure'\): no unit",
    ),
    # NaN and text
    (
        GOOD.replace("0.5,0.002,20.0", "0.5,nan,20.0"),
        r"line 5, column 2 \(volumetric_strain\): 'nan' is not a finite number",
    ),
    (GOOD.replace("1.0,0.003,30.5", "1.0,0.003,abc"), r"line 6, column 3 \(deviator_stress\): 'abc'"),
    # percent written as a fraction
    (
        GOOD.replace("axial_strain [%]", "axial_strain [-]").replace("0.5,0.002", "5.0,0.002"),
        r"line 5, column 1 \(axial_strain\): 5 as a fraction.*axial_strain \[%\]",
    ),
    # unsorted or unloading
    (
        GOOD.replace("1.0,0.003", "0.4,0.003"),
        r"line 6, column 1 \(axial_strain\): 0.4 after 0.5.*must not fall.*sort the record by time",
    ),
    # a negative pressure
    (GOOD.replace("30.5,10,", "30.5,-10,"), r"line 6, column 4 \(cell_pressure\): -10 kPa"),
    # extension positive: the axial strain of a compression test written negative
    (
        GOOD.replace("0.5,0.002", "-0.5,0.002").replace("1.0,0.003", "-1.0,0.003"),
        r"line 5, column 1 \(axial_strain\): -0.5 after 0.*falls below zero.*compression positive",
    ),
    # a fraction under a [%] header: 1 % written 0.01 never exceeds 0.2 %
    (
        GOOD.replace("0.5,0.002", "0.005,0.002").replace("1.0,0.003", "0.01,0.003"),
        r"line 3, column 1 \(axial_strain \[%\]\): the axial strain never exceeds 0.01 %.*fraction under a "
        r"\[%\] header\? If so, write 'axial_strain \[-\]'",
    ),
    # percent under a [-] header: 0.8 would be 80 %
    (
        GOOD.replace("axial_strain [%]", "axial_strain [-]").replace("1.0,0.003", "0.8,0.003"),
        r"column 1 \(axial_strain \[-\]\): the axial strain reaches 0.8, that is 80 %.*in percent",
    ),
    # dilation written positive: the volumetric strain falls from the start of loading
    (
        GOOD.replace("0.5,0.002", "0.5,-0.002").replace("1.0,0.003", "1.0,-0.003"),
        r"line 3, column 2 \(volumetric_strain\): the volumetric strain falls while the specimen is "
        r"compressed.*Is dilation written positive\? membrax takes compression positive.*--dilation-positive",
    ),
    # bulging written positive
    (
        GOOD.replace("volumetric_strain [-]", "radial_strain [-]"),
        r"column 2 \(radial_strain\): the radial strain grows while the specimen is compressed.*"
        r"Is bulging written positive\?",
    ),
]


@pytest.mark.parametrize(("text", "message"), BAD_FILES)
def test_each_bad_file_names_the_line_the_column_and_the_fix(tmp_path, text, message):
    with pytest.raises(LabRecordError, match=message):
        read_lab_record(_write(tmp_path, text))


def test_an_empty_or_missing_file_is_refused(tmp_path):
    with pytest.raises(LabRecordError, match="no header"):
        read_lab_record(_write(tmp_path, "# only a comment\n"))
    with pytest.raises(LabRecordError, match="fewer than 2 rows"):
        read_lab_record(_write(tmp_path, GOOD.split("\n0.5")[0] + "\n"))
    with pytest.raises(FileNotFoundError):
        read_lab_record(tmp_path / "none.csv")


@pytest.mark.parametrize(("text", "message"), BAD_FILES)
def test_membrax_correct_names_each_bad_file_and_writes_nothing(tmp_path, capsys, monkeypatch, text, message):
    from membrax import cli

    monkeypatch.chdir(tmp_path)  # the default output folder

    path = _write(tmp_path, text)
    argv = ["correct", str(path), "--specimen-diameter-mm", "150", "--particle-size-mm", "20"]
    argv += ["--membrane-thickness-mm", "2", "--membrane-modulus-kpa", "1400"]
    assert cli.main(argv) == 2
    assert re.search(message, capsys.readouterr().err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lab.csv"]  # nothing written, not even half


def _rows(record):
    return np.stack(
        [record.axial_strain, record.volumetric_strain, record.axial_stress, record.cell_pressure]
    )


def test_a_spreadsheet_export_with_a_byte_order_mark_semicolons_and_decimal_commas_is_the_same_record(
    tmp_path,
):
    clean = read_lab_record(_write(tmp_path, GOOD))
    semicolons = GOOD.replace(",", ";").replace("0.5;", "0,5;").replace("30.5;", "30,5;")
    semicolons = semicolons.replace("0.002;", "0,002;").replace("1.0;", "1,0;").replace("0.003;", "0,003;")
    path = tmp_path / "excel.csv"
    path.write_text(semicolons, encoding="utf-8-sig")  # Excel's "CSV UTF-8": a byte-order mark first
    assert path.read_bytes().startswith(b"\xef\xbb\xbf")
    exported = read_lab_record(path)
    np.testing.assert_array_equal(_rows(exported), _rows(clean))
    assert exported.notes == ("columns separated by semicolons; decimal commas read as points",)
    assert clean.notes == ()
    tabs = tmp_path / "tabs.txt"
    tabs.write_text(GOOD.replace(",", "\t"), encoding="utf-16")  # "Unicode text": UTF-16 with its mark
    np.testing.assert_array_equal(_rows(read_lab_record(tabs)), _rows(clean))


def test_an_xlsx_sheet_is_the_same_record_as_its_csv(tmp_path):
    import openpyxl

    clean = read_lab_record(_write(tmp_path, GOOD))
    book = openpyxl.Workbook()
    sheet = book.active
    sheet.title = "test 7"
    for line in GOOD.splitlines():
        cells = [line] if line.startswith("#") else line.split(",")
        sheet.append([float(c) if c[0].isdigit() else c for c in cells])
    book.save(tmp_path / "lab.xlsx")
    record = read_lab_record(tmp_path / "lab.xlsx")
    np.testing.assert_array_equal(_rows(record), _rows(clean))
    assert record.comments == clean.comments
    sheet["B5"] = "n/a"
    book.save(tmp_path / "bad.xlsx")
    with pytest.raises(
        LabRecordError, match=r"bad.xlsx, sheet 'test 7', row 5, column 2 \(volumetric_strain\)"
    ):
        read_lab_record(tmp_path / "bad.xlsx")


def test_repeated_axial_strains_are_averaged_and_counted(tmp_path):
    # A logger holding its strain reading for three rows while the load creeps up: one row, their mean.
    text = GOOD.replace(
        "0.5,0.002,20.0,10,31.0\n", "0.5,0.002,20.0,10,31.0\n0.5,0.002,21.0,10,0\n0.5,0.005,23.0,10,0\n"
    )
    record = read_lab_record(_write(tmp_path, text))
    np.testing.assert_allclose(record.axial_strain, [0.0, 0.005, 0.01], rtol=1e-15)
    np.testing.assert_allclose(record.axial_stress, [1e4, 1e4 + 1e3 * (20 + 21 + 23) / 3, 4.05e4], rtol=1e-15)
    np.testing.assert_allclose(record.volumetric_strain[1], 0.003, rtol=1e-12)
    assert record.notes == (
        "2 readings repeat the axial strain of the reading before (a logger holding its value); each run of "
        "equal axial strains is averaged into one row: 3 rows of 5",
    )


def test_a_dilation_positive_record_is_read_with_the_flag_as_its_twin(tmp_path):
    clean = read_lab_record(_write(tmp_path, GOOD))
    twin = GOOD.replace("0.5,0.002", "0.5,-0.002").replace("1.0,0.003", "1.0,-0.003")
    record = read_lab_record(_write(tmp_path, twin, "twin.csv"), dilation_positive=True)
    np.testing.assert_array_equal(_rows(record), _rows(clean))
    assert "volumetric_strain negated (--dilation-positive)" in record.notes[0]


BINARY_FILES = [
    # Excel 97-2003 (an OLE compound file), the "byte 0xd0"
    (
        b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(600),
        r"is an Excel 97-2003 workbook \(.xls\), not a text CSV",
    ),
    # a picture saved under .csv
    (b"\x89PNG\r\n\x1a\n" + bytes(64), r"is not a text CSV \(it holds binary data\): byte 0x89 at offset 0"),
    # a legacy-encoded text file (a degree sign in Latin-1)
    (b"# 20 \xb0C\n" + GOOD.encode(), r"is not UTF-8 text: byte 0xb0 at offset 5"),
    # a zip that is no workbook
    (b"PK\x03\x04" + bytes(64), r"is a zip file but not a readable .xlsx workbook"),
]


@pytest.mark.parametrize(("data", "message"), BINARY_FILES)
def test_a_file_that_is_not_a_text_csv_is_named_and_explained(tmp_path, data, message):
    path = tmp_path / "lab.csv"
    path.write_bytes(data)
    with pytest.raises(
        LabRecordError, match=f"{re.escape(str(path))} {message}.*save it from the spreadsheet"
    ):
        read_lab_record(path)


@pytest.mark.parametrize(
    "header",
    [
        "Axial strain (%),Volumetric strain [-],Deviator stress (kPa),Cell pressure [kPa],Time (s)",
        "AXIAL_STRAIN [%], volumetric-strain (-) ,deviator stress [KPA],cell  pressure (kpa),Remarks",
        "Time (s),axial strain[%],Volumetric Strain(-),Deviator_Stress [kPa],Cell Pressure [kPa],σ1 (kPa)",
    ],
)
def test_headers_as_laboratories_write_them_read_the_same_record(tmp_path, header):
    """Case, spaces, hyphens and the unit in parentheses aside; other columns ignored whatever their form."""
    reference = read_lab_record(_write(tmp_path, GOOD))
    rows = ["0.0,0.0,0.0,10", "0.5,0.002,20.0,10", "1.0,0.003,30.5,10"]
    if header.startswith("Time"):
        rows = [f"{60 * i},{row},0" for i, row in enumerate(rows)]
    else:
        rows = [f"{row},{i}" for i, row in enumerate(rows)]
    record = read_lab_record(_write(tmp_path, header + "\n" + "\n".join(rows) + "\n", "lab2.csv"))
    for name in ("axial_strain", "volumetric_strain", "axial_stress", "cell_pressure"):
        np.testing.assert_array_equal(getattr(record, name), getattr(reference, name))


def test_every_problem_of_a_header_is_reported_at_once(tmp_path):
    text = "axial_strain [%],Volumetric strain (ml),deviator_stress,Axial strain [-]\n0,0,0,0\n1,1,1,1\n"
    with pytest.raises(LabRecordError) as caught:
        read_lab_record(_write(tmp_path, text))
    message = str(caught.value)
    assert "line 1 (header" in message
    assert "column 4 ('Axial strain [-]') repeats column 1" in message
    assert "no column 'cell_pressure'" in message
    assert "column 2 ('Volumetric strain (ml)'): unknown unit 'ml'" in message
    assert "column 3 ('deviator_stress'): no unit" in message


def test_a_workbook_s_sheet_is_chosen_by_name_or_number_and_named_when_missing(tmp_path):
    import openpyxl

    clean = read_lab_record(_write(tmp_path, GOOD))
    book = openpyxl.Workbook()
    book.active.title = "Notes"
    book.active.append(["Test 7, ballast, 25 kPa"])
    data = book.create_sheet("Data")
    for line in GOOD.splitlines():
        cells = [line] if line.startswith("#") else line.split(",")
        data.append([float(c) if c[0].isdigit() else c for c in cells])
    book.save(tmp_path / "two.xlsx")
    with pytest.raises(LabRecordError) as caught:
        read_lab_record(tmp_path / "two.xlsx")
    message = str(caught.value)
    assert "no column 'axial_strain'" in message and "The workbook's sheets: 'Notes', 'Data'" in message
    assert "Sheet 'Data' has them: pass --sheet 'Data'" in message
    for sheet in ("Data", "2", 2):
        record = read_lab_record(tmp_path / "two.xlsx", sheet=sheet)
        np.testing.assert_array_equal(_rows(record), _rows(clean))
        assert "read sheet 2, 'Data', of the workbook" in record.notes
    with pytest.raises(
        LabRecordError, match=r"no sheet 'Raw'; the workbook's sheets are 1 'Notes', 2 'Data'"
    ):
        read_lab_record(tmp_path / "two.xlsx", sheet="Raw")
    with pytest.raises(LabRecordError, match="is a text file, not a workbook: leave out --sheet 2"):
        read_lab_record(_write(tmp_path, GOOD), sheet=2)


def test_a_cell_pressure_that_changes_during_the_record_is_refused_at_its_line(tmp_path):
    """25 → 60 kPa (a second stage) refused at the row it changes; 25 ± 1 kPa and 100 ± 5 kPa read."""
    rows = "axial_strain [%],volumetric_strain [%],deviator_stress [kPa],cell_pressure [kPa]\n"
    staged = rows + "0,0,0,25\n0.5,0.1,20,25\n1,0.2,30,60\n"
    with pytest.raises(LabRecordError, match=r"line 4, column 4 \(cell_pressure\): 60 kPa against 25 kPa"):
        read_lab_record(_write(tmp_path, staged))
    held = rows + "0,0,0,25\n0.5,0.1,20,26\n1,0.2,30,24\n"
    np.testing.assert_allclose(
        read_lab_record(_write(tmp_path, held, "h.csv")).cell_pressure, [25e3, 26e3, 24e3]
    )
    high = rows + "0,0,0,100\n0.5,0.1,20,105\n1,0.2,30,95\n"
    assert read_lab_record(_write(tmp_path, high, "g.csv")).cell_pressure.max() == pytest.approx(105e3)
    with pytest.raises(LabRecordError, match="more than 5 %"):
        read_lab_record(_write(tmp_path, high.replace("95\n", "94\n"), "x.csv"))
