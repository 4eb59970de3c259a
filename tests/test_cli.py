"""The `membrax theory` table: its numbers against hand calculations."""

import math
import re
import subprocess
import sys

from membrax import cli


def _row(report, first_cell, section=""):
    """Numbers on the first line starting with ``first_cell`` after the heading containing ``section``."""
    report = report[report.index(section) :]
    for line in report.splitlines():
        cells = line.split()
        if cells and cells[0] == first_cell:
            return [float(x) for x in re.findall(r"-?\d+\.\d+", line)]
    raise AssertionError(f"no row {first_cell!r}")


def test_theory_table_numbers(capsys):
    assert cli.main(["theory"]) == 0
    report = capsys.readouterr().out
    # Rowe: both conventions (reference §12.6).
    assert _row(report, "exact:")[-1] == 43.79
    assert _row(report, "paper:")[-1] == 43.85
    # Bolton at 10 kPa: I_R = 0.758621 (10 − ln 10) − 1 = 4.8394; Bolton 50.52, clipped 48.00, Eq. 1 52.52.
    assert _row(report, "10", "Bolton")[:5] == [4.8394, 50.52, 48.00, 52.52, 44.38]
    # ASTM at 5 %: 4 · 1400 kPa · 2.5 mm · 0.05 / 250 mm = 2.8 kPa, and ∝ t_m.
    assert _row(report, "2.50", "ASTM")[-1] == 2.8
    assert _row(report, "5.00", "ASTM")[-1] == 5.6
    # Molenkamp & Luger at 100 kPa, 2.5 mm by hand.
    ml = 0.275 * (1 + 0.35047) ** (4 / 9) * (25 / 2.5) ** (1 / 3) * (100 / 1400) ** (1 / 3)
    assert math.isclose(_row(report, "100", "Molenkamp")[-3], round(ml, 4), abs_tol=1e-4)
    # The inflation limit of 1 mm of 700 kPa over the square window a = (√2 − 1) 12.5 mm by hand:
    # neo-Hookean 1.8353 (700/3) / a; Gent (J_m = 97.2) 1.8827 (700/3) / a; below J_m = 32.6 no limit.
    aperture = (math.sqrt(2.0) - 1.0) * 12.5
    neo_hookean, gent = _row(report, "1.00", "Inflation limit")[1:3]
    assert neo_hookean == round(1.8353 * 700.0 / 3.0 / aperture, 1) == 82.7
    assert gent == round(1.8827 * 700.0 / 3.0 / aperture, 1) == 84.8
    inflation = report[report.index("Inflation limit") :]
    assert inflation.splitlines()[3].split()[-1] == "none"


def test_console_entry_point_runs_theory():
    result = subprocess.run(
        [sys.executable, "-m", "membrax.cli", "theory"], capture_output=True, text=True, check=True
    )
    assert "43.85" in result.stdout and "43.79" in result.stdout
