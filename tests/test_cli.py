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


_CACHED = """
import json, jax, jax.numpy as jnp
from membrax.cli import use_compilation_cache
hits = []
jax.monitoring.register_event_listener(lambda name, **_: hits.append(name))
folder = use_compilation_cache()
n = 1000
total = jax.jit(lambda x: jnp.sum(x * x))(jnp.arange(1, n + 1, dtype=jnp.int32))
print(json.dumps({"folder": str(folder), "sum": int(total),
                  "hits": hits.count("/jax/compilation_cache/cache_hits")}))
"""


def test_the_command_line_keeps_its_programs_in_membrax_s_cache_folder_for_the_next_command(tmp_path):
    """``membrax``'s entry point turns on JAX's persistent cache in membrax's cache folder (``jax/`` in
    ``$MEMBRAX_CACHE_DIR``): a second process loads the program the first compiled (a cache hit) and gets
    the same Σ k² = n(n + 1)(2n + 1)/6; ``MEMBRAX_COMPILATION_CACHE=0`` leaves it off (no folder)."""
    import json
    import os

    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env.update(MEMBRAX_CACHE_DIR=str(tmp_path), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")

    def run(**extra):
        done = subprocess.run(
            [sys.executable, "-c", _CACHED], env={**env, **extra}, capture_output=True, text=True, check=True
        )
        return json.loads(done.stdout.strip().splitlines()[-1])

    first, second = run(), run()
    assert first["folder"] == second["folder"] == str(tmp_path / "jax")
    assert first["sum"] == second["sum"] == 1000 * 1001 * 2001 // 6
    assert first["hits"] == 0 and second["hits"] >= 1
    assert any((tmp_path / "jax").iterdir())
    off = run(MEMBRAX_COMPILATION_CACHE="0")
    assert off["folder"] == "None" and off["hits"] == 0 and off["sum"] == first["sum"]
