"""calibrate.lab: laboratory records read in SI units, and every bad file refused naming line, column, fix."""

import math

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
        r"line 3 \(header\): no column 'cell_pressure'",
    ),
    # an unknown unit, and a unit left out
    (
        GOOD.replace("deviator_stress [kPa]", "deviator_stress [psi]"),
        r"line 3, column 3 \(deviator_stress\): unknown unit 'psi'.*kPa",
    ),
    (
        GOOD.replace("cell_pressure [kPa]", "cell_pressure"),
        r"column 4 \(cell_pressure\): unknown unit None",
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
        r"line 6, column 1 \(axial_strain\): 0.4 after 0.5.*must increase",
    ),
    # a negative pressure
    (GOOD.replace("30.5,10,", "30.5,-10,"), r"line 6, column 4 \(cell_pressure\): -10 kPa"),
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
def test_membrax_correct_names_each_bad_file_and_writes_nothing(tmp_path, capsys, text, message):
    import re

    from membrax import cli

    path = _write(tmp_path, text)
    argv = ["correct", str(path), "--specimen-diameter-mm", "150", "--particle-size-mm", "20"]
    argv += ["--membrane-thickness-mm", "2", "--membrane-modulus-kpa", "1400"]
    assert cli.main(argv) == 2
    assert re.search(message, capsys.readouterr().err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lab.csv"]  # nothing written, not even half
