"""A corrected record's report: the CSV, the plot and ``membrax correct``'s files.

Contract. :func:`write_correction` writes a :class:`calibrate.correct.CorrectedRecord` as a CSV (σ1, σ3,
φ' by method, the fitted method's band, extrapolation and abstention factors, and the alternate radial
target's fitted columns where the correction has one; a header line says which internal stresses the
fitted columns reproduce, :func:`target_words`) and a plot (σ1, σ3, φ' side by side, titled with the
test's σc, membrane and specimen, :func:`correction_title`), atomically: a failure leaves no file
half-written. ``membrax correct`` is :func:`correct_file`: it never writes over the record it reads
(:func:`output_paths`), and writes into the working folder by default, never beside a record inside the
package; a record over :data:`PROGRESS_ROWS` readings is told stage by stage.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np

from calibrate import lab, persistence
from calibrate.correct import (
    LABELS,
    METHODS,
    CorrectedRecord,
    LabSpecimen,
    correct_record,
    default_corrections,
)
from calibrate.size_effect import size_effect_lines

__all__ = [
    "PROGRESS_ROWS",
    "correct_file",
    "correction_title",
    "output_paths",
    "plot_correction",
    "target_words",
    "write_correction",
]


def target_words(result: CorrectedRecord) -> str:
    """Which internal stresses the fitted columns reproduce, in a laboratory's words (a CSV header line)."""
    words = {
        "received": "the radial load the specimen receives over the membrane's projected area",
        "section_4_3": "the paper's 4.3 internal radial stress",
    }
    line = f"fitted: sigma_1 the paper's 4.3 internal axial stress, sigma_3 {words[result.radial_target]}"
    if result.alternate is not None:
        name = result.alternate.radial_target
        line += f"; the *_fitted_{name} columns: sigma_3 {words[name]} (docs/model.md)"
    return line


def _csv_text(result: CorrectedRecord, header_lines) -> str:
    record = result.record
    columns = {
        "axial_strain [%]": 100.0 * record.axial_strain,
        "volumetric_strain [%]": 100.0 * record.volumetric_strain,
        "radial_strain [%]": 100.0 * record.radial_strain,
        "cell_pressure [kPa]": 1e-3 * record.cell_pressure,
    }
    for method in METHODS:
        columns[f"sigma_1_{method} [kPa]"] = 1e-3 * result.sigma_1[method]
        columns[f"sigma_3_{method} [kPa]"] = 1e-3 * result.sigma_3[method]
        columns[f"friction_angle_{method} [deg]"] = result.friction_angle[method]
    columns["sigma_1_fitted_std [kPa]"] = 1e-3 * result.std["sigma_1"]
    columns["sigma_3_fitted_std [kPa]"] = 1e-3 * result.std["sigma_3"]
    columns["friction_angle_fitted_std [deg]"] = result.std["friction_angle"]
    columns["fitted_extrapolation [-]"] = result.extrapolation
    # Per record, repeated on each row so that every reading carries what was done to it.
    columns["fitted_shrink_axial [-]"] = np.full(record.axial_strain.shape, result.shrink[0])
    columns["fitted_shrink_radial [-]"] = np.full(record.axial_strain.shape, result.shrink[1])
    other = result.alternate
    if other is not None:  # the fitted method with the other radial target, beside (module docstring)
        suffix = f"fitted_{other.radial_target}"
        columns[f"sigma_1_{suffix} [kPa]"] = 1e-3 * other.sigma_1["fitted"]
        columns[f"sigma_3_{suffix} [kPa]"] = 1e-3 * other.sigma_3["fitted"]
        columns[f"friction_angle_{suffix} [deg]"] = other.friction_angle["fitted"]
        columns[f"friction_angle_{suffix}_std [deg]"] = other.std["friction_angle"]
    out = io.StringIO()
    for line in header_lines:
        out.write(f"# {line}\n")
    out.write(",".join(columns) + "\n")
    table = np.stack(list(columns.values()), axis=1)
    np.savetxt(out, table, delimiter=",", fmt="%.8g")
    return out.getvalue()


def plot_correction(result: CorrectedRecord, title: str = "", reference=None):
    """σ1, σ3 and φ' against axial strain by every method, the fitted one with its ±1 s.d. band.

    Args:
      result: the :class:`CorrectedRecord`.
      title: the figure's title.
      reference: optional (σ1, σ3) in Pa the specimen really carried (a simulation's internal stresses),
        drawn in grey.
    """
    import matplotlib

    from membrax.triaxial.analysis import friction_angle_deg

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    strain = 100.0 * result.record.axial_strain
    figure, axes = plt.subplots(1, 3, figsize=(13, 4), constrained_layout=True)
    quantities = (
        (result.sigma_1, 1e-3, "σ1 (kPa)", result.std["sigma_1"]),
        (result.sigma_3, 1e-3, "σ3 (kPa)", result.std["sigma_3"]),
        (result.friction_angle, 1.0, "mobilised φ' (°)", result.std["friction_angle"]),
    )
    styles = {
        "uncorrected": "k-",
        "astm": "C0--",
        "henkel_gilbert": "C1-.",
        "kuerbis_vaid": "C2:",
        "fitted": "C3-",
    }
    labels = dict(LABELS)
    if np.all(np.isnan(result.friction_angle["fitted"])):
        labels["fitted"] += ": withheld, outside its fitted range"
    elif np.any(result.extrapolation > 0.0):
        labels["fitted"] += ", band widened outside its fitted range"
    if min(result.shrink) < 1.0 and not np.all(np.isnan(result.friction_angle["fitted"])):
        labels["fitted"] += f", abstains in part (σ1 ×{result.shrink[0]:.2f}, σ3 ×{result.shrink[1]:.2f})"
    truth = None
    if reference is not None:
        s1, s3 = (np.asarray(v, dtype=np.float64) for v in reference)
        truth = (s1, s3, friction_angle_deg(s1, s3))
    for k, (axis, (values, scale, label, spread)) in enumerate(zip(axes, quantities, strict=True)):
        if truth is not None:
            axis.plot(strain, scale * truth[k], color="0.6", lw=4, alpha=0.6, label="internal (simulated)")
        for method in METHODS:
            axis.plot(strain, scale * values[method], styles[method], label=labels[method])
        fitted = scale * values["fitted"]
        axis.fill_between(
            strain, fitted - scale * spread, fitted + scale * spread, color="C3", alpha=0.25, lw=0
        )
        axis.set(xlabel="axial strain (%)", ylabel=label)
    # The first records (ε_a → 0, σ1 → σc) have φ' → 0; scale the φ' axis to the rest of the test.
    later = strain >= 0.5
    if np.any(later):
        lowest = np.nanmin([np.nanmin(result.friction_angle[m][later]) for m in METHODS])
        axes[2].set_ylim(bottom=lowest - 2.0)
    axes[2].legend(fontsize=8, loc="lower right")
    if title:
        figure.suptitle(title)
    return figure


def correction_title(result: CorrectedRecord, name: str) -> str:
    """A plot's title: the test's name, its cell pressure, membrane and specimen, in a laboratory's units."""
    inputs = result.inputs

    def first(key):
        return float(np.ravel(inputs[key])[0])

    return (
        f"{name}: σc {1e-3 * float(np.median(result.record.cell_pressure)):.3g} kPa, membrane "
        f"{1e3 * first('membrane_thickness'):.3g} mm of {1e-3 * first('membrane_modulus'):.4g} kPa, specimen "
        f"{1e3 * first('specimen_diameter'):.4g} mm across, d50 {1e3 * first('particle_diameter'):.3g} mm"
    )


def write_correction(result: CorrectedRecord, csv_path, plot_path=None, header_lines=()) -> list[Path]:
    """Write the CSV (and the plot, PNG) of a corrected record atomically; return the paths written."""
    from membrax.io.files import atomic_write_bytes

    written = []
    csv_path = Path(csv_path)
    text = _csv_text(result, header_lines)  # built first: nothing is written if this fails
    figure = None
    if plot_path is not None:
        figure = plot_correction(result, title=correction_title(result, csv_path.stem))
        image = io.BytesIO()
        figure.savefig(image, format="png", dpi=120)
        import matplotlib.pyplot as plt

        plt.close(figure)
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(csv_path, text.encode())
    written.append(csv_path)
    if figure is not None:
        plot_path = Path(plot_path)
        plot_path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(plot_path, image.getvalue())
        written.append(plot_path)
    return written


def output_paths(record_path, out=None, plot: bool = True) -> tuple[Path, Path | None]:
    """The CSV and plot ``membrax correct`` writes: ``out``, or ``<record>_corrected.csv`` in the working dir.

    Raises:
      ValueError: ``out`` does not end in ``.csv``, or the CSV or plot is the record itself (by resolved
        path): the laboratory's raw record is never overwritten.
    """
    record_path = Path(record_path)
    csv_path = Path(out) if out is not None else Path.cwd() / f"{record_path.stem}_corrected.csv"
    if csv_path.suffix.lower() != ".csv":
        raise ValueError(
            f"--out {csv_path}: give a .csv file (the plot is written beside it as .png), e.g. "
            f"--out {csv_path.with_suffix('.csv').name}."
        )
    plot_path = csv_path.with_suffix(".png") if plot else None
    source = record_path.resolve()
    for path in (csv_path, plot_path):
        if path is not None and (path.resolve() == source or (path.exists() and path.samefile(source))):
            raise ValueError(
                f"--out {out}: {path} is the record being corrected; membrax never writes over a "
                f"laboratory record. Give another name, e.g. --out {record_path.stem}_corrected.csv."
            )
    return csv_path, plot_path


#: Records longer than this many readings get a line per stage from :func:`correct_file`'s ``progress``.
PROGRESS_ROWS = 100_000


def correct_file(
    record_path,
    specimen: LabSpecimen,
    model_path=None,
    out=None,
    plot: bool = True,
    dilation_positive: bool = False,
    progress=None,
    sheet=None,
):
    """``membrax correct``: read ``record_path``, correct it, write ``out`` (CSV) and its plot.

    Args:
      record_path: the laboratory record, CSV or .xlsx (:func:`calibrate.lab.read_lab_record`).
      specimen: the :class:`LabSpecimen`.
      model_path: a ``corrections.json`` of ``membrax fit`` (default the shipped correction).
      out: the CSV to write (default ``<record>_corrected.csv`` in the working folder); the plot is the same
        name with ``.png``. Never the record itself (:func:`output_paths`).
      plot: write the plot.
      dilation_positive: the record's volumetric or radial strain is written dilation positive.
      progress: called with a line of text before each stage (reading, correcting, writing) of a record
        longer than :data:`PROGRESS_ROWS` readings, e.g. ``print``; None says nothing.
      sheet: a workbook's sheet, by name or number from 1 (:func:`calibrate.lab.read_lab_record`).

    Returns:
      (the :class:`CorrectedRecord`, the paths written).

    Raises:
      FileNotFoundError, calibrate.lab.LabRecordError, ValueError: a missing or bad record or model file,
        or an output that would overwrite the record, named with the fix; nothing is written.
    """
    csv_path, plot_path = output_paths(record_path, out, plot)
    size = Path(record_path).stat().st_size if Path(record_path).is_file() else 0
    if progress is not None and size > 40 * PROGRESS_ROWS:  # ~40 bytes a reading
        progress(f"reading {Path(record_path).name} ({size / 1e6:.0f} MB)")
    record = lab.read_lab_record(record_path, dilation_positive=dilation_positive, sheet=sheet)
    corrections = default_corrections() if model_path is None else persistence.load_corrections(model_path)
    rows = record.axial_strain.size
    say = progress if progress is not None and rows > PROGRESS_ROWS else (lambda text: None)
    say(f"correcting {rows:,} readings of {Path(record_path).name} by five methods")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # returned in the result; the caller reports them once
        result = correct_record(record, specimen, corrections)
    header = [
        f"membrane corrections of {Path(record_path).name} by membrax correct",
        f"specimen diameter {1e3 * specimen.specimen_diameter:g} mm, particle size "
        f"{1e3 * specimen.particle_diameter:g} mm, membrane {1e3 * specimen.membrane_thickness:g} mm of "
        f"{1e-3 * specimen.membrane_modulus:g} kPa"
        + (
            ""
            if specimen.solid_fraction is None
            else f", void ratio {1.0 / specimen.solid_fraction - 1.0:.3g}"
        )
        + ("" if specimen.height is None else f", specimen height {1e3 * specimen.height:g} mm"),
        f"fitted model {corrections.model.name!r} from {model_path or 'the shipped default'} "
        f"(membrax {corrections.provenance.get('membrax_version', '?')}); std: one standard deviation, "
        "widened by 1 + fitted_extrapolation outside the fitted range; fitted_shrink_axial/_radial: the "
        "factors the abstention rule scaled the fitted sigma_1/sigma_3 corrections by (1: kept)",
        target_words(result),
        *size_effect_lines(specimen.specimen_diameter / specimen.particle_diameter),
        "conventions: compression positive; strains in %, stresses in kPa",
        *(f"source: {line}" for line in record.comments),
        *(f"read: {line}" for line in record.notes),
        *(f"warning: {message}" for message in result.warnings),
    ]
    say(f"writing {csv_path}" + ("" if plot_path is None else f" and {plot_path.name}"))
    paths = write_correction(result, csv_path, plot_path, header)
    return result, paths
