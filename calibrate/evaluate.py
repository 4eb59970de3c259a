"""Simulated tests as laboratory records, and how close each correction brings φ' to the internal φ'.

Contract. :func:`lab_record_of` turns one member of a sweep (``sweep.nc``) into what a laboratory would
have measured, a :class:`calibrate.lab.LabRecord` (external stresses: the ram's σ1 and the cell pressure;
ε_a and ε_v from the start of shearing), together with its :class:`calibrate.correct.LabSpecimen` and the
internal stresses the specimen carried, which a laboratory cannot measure: σ1 the paper's §4.3, σ3 the
radial target asked for (:data:`calibrate.datasets.RADIAL_TARGETS`; a correction is scored against the one
it reproduces, its ``radial_target``).
:func:`friction_angle_errors` corrects it by every method (:func:`calibrate.correct.correct_record`) and
returns, per method, the mean and the worst |φ'_method − φ'_internal| over the records with
0 < ε_a ≤ 10 % (``max_strain``). :func:`held_out_errors` does this for every member of a sweep and pools
them. :func:`write_example_record` writes a member as the shipped example record (CSV, labelled synthetic,
the internal stresses in columns ``membrax correct`` does not read; :func:`write_member_record` any member),
and :func:`corrected_csv_errors` scores ``membrax correct``'s output for such a record against both internal
σ3, as a user would meet the correction.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from calibrate import correct, datasets, lab
from membrax.config import characteristic_size_mm, compaction_state

__all__ = [
    "EXAMPLE_ARGUMENTS_PREFIX",
    "SPECIMEN_FLAGS",
    "INTERNAL_COLUMNS",
    "VOID_RATIO_FLAG",
    "HEIGHT_FLAG",
    "corrected_csv_errors",
    "csv_columns",
    "element_errors",
    "example_arguments",
    "example_argv",
    "example_height_mm",
    "example_void_ratio",
    "read_example_record",
    "friction_angle_errors",
    "friction_angle_table",
    "held_out_errors",
    "lab_record_of",
    "write_example_record",
    "write_lab_csv",
    "write_resampled_record",
    "write_member_record",
]

#: The comment of the example record that carries its ``membrax correct`` arguments.
EXAMPLE_ARGUMENTS_PREFIX = "membrax correct arguments:"
#: Those arguments' flags, in the order of :meth:`calibrate.correct.LabSpecimen.from_mm_kpa`.
SPECIMEN_FLAGS = (
    "--specimen-diameter-mm",
    "--particle-size-mm",
    "--membrane-thickness-mm",
    "--membrane-modulus-kpa",
)
#: The optional flag of the specimen's void ratio (:meth:`calibrate.correct.LabSpecimen.from_mm_kpa`).
VOID_RATIO_FLAG = "--void-ratio"
#: The optional flag of the specimen's height after consolidation.
HEIGHT_FLAG = "--specimen-height-mm"
#: A member record's internal-stress columns (:func:`write_member_record`): σ1, and σ3 per radial target.
INTERNAL_COLUMNS = {
    "sigma_1": "internal_sigma_1",
    "section_4_3": "internal_sigma_3",
    "received": "internal_sigma_3_received",
}


def read_example_record(radial_target: str | None = None):
    """The shipped example record: (LabRecord, LabSpecimen, internal σ1, internal σ3), stresses in Pa.

    Args:
      radial_target: which internal σ3 (:data:`INTERNAL_COLUMNS`: ``"received"`` or ``"section_4_3"``);
        default the shipped correction's own target.
    """
    if radial_target is None:
        radial_target = correct.default_corrections().radial_target
    with correct.example_record_path() as path:
        record = lab.read_lab_record(path)
        lines = path.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    names = [cell.split("[")[0].strip() for cell in lines[header].split(",")]
    table = np.loadtxt(lines[header + 1 :], delimiter=",", ndmin=2)
    specimen = correct.LabSpecimen.from_mm_kpa(
        *example_arguments(record.comments),
        void_ratio=example_void_ratio(record.comments),
        specimen_height_mm=example_height_mm(record.comments),
    )
    internal_1 = 1e3 * table[:, names.index(INTERNAL_COLUMNS["sigma_1"])]
    internal_3 = 1e3 * table[:, names.index(INTERNAL_COLUMNS[radial_target])]
    return record, specimen, internal_1, internal_3


def example_arguments(comments) -> tuple[float, float, float, float]:
    """(specimen diameter mm, particle size mm, membrane thickness mm, modulus kPa) from a record's comments.

    Raises:
      ValueError: no comment starting with :data:`EXAMPLE_ARGUMENTS_PREFIX`.
    """
    for line in comments:
        if line.startswith(EXAMPLE_ARGUMENTS_PREFIX):
            words = line[len(EXAMPLE_ARGUMENTS_PREFIX) :].split()
            values = dict(zip(words[::2], words[1::2], strict=True))
            return tuple(float(values[flag]) for flag in SPECIMEN_FLAGS)
    raise ValueError(f"no '# {EXAMPLE_ARGUMENTS_PREFIX} ...' comment in the record.")


def example_argv(comments) -> list[str]:
    """The ``membrax correct`` options of a record's :data:`EXAMPLE_ARGUMENTS_PREFIX` comment, as argv words.

    Raises:
      ValueError: no such comment.
    """
    for line in comments:
        if line.startswith(EXAMPLE_ARGUMENTS_PREFIX):
            return line[len(EXAMPLE_ARGUMENTS_PREFIX) :].split()
    raise ValueError(f"no '# {EXAMPLE_ARGUMENTS_PREFIX} ...' comment in the record.")


def _example_option(comments, flag: str) -> float | None:
    """The value of ``flag`` in a record's :data:`EXAMPLE_ARGUMENTS_PREFIX` comment, or None."""
    for line in comments:
        if line.startswith(EXAMPLE_ARGUMENTS_PREFIX):
            words = line[len(EXAMPLE_ARGUMENTS_PREFIX) :].split()
            values = dict(zip(words[::2], words[1::2], strict=True))
            return float(values[flag]) if flag in values else None
    return None


def example_void_ratio(comments) -> float | None:
    """The void ratio in a record's :data:`EXAMPLE_ARGUMENTS_PREFIX` comment, or None when it has none."""
    return _example_option(comments, VOID_RATIO_FLAG)


def example_height_mm(comments) -> float | None:
    """The specimen height (mm) in a record's :data:`EXAMPLE_ARGUMENTS_PREFIX` comment, or None."""
    return _example_option(comments, HEIGHT_FLAG)


def lab_record_of(config: dict, rows, radial_target: str = datasets.LEGACY_RADIAL_TARGET):
    """(LabRecord, LabSpecimen, internal σ1, internal σ3) of one sweep member (module docstring).

    Records whose axial strain does not exceed the previous one's (the platens start from rest) are
    dropped, as a laboratory's logger would.

    Args:
      config: the member's configuration (``cell_pressure_kpa`` kPa, ``particle_diameter_mm`` or
        ``grading`` and ``membrane_thickness_mm`` mm, ``membrane_modulus_kpa`` kPa); the particle size is
        :func:`membrax.config.characteristic_size_mm` (d50 of a grading).
      rows: its shearing records (stresses in Pa, strains dimensionless, ``platen_area`` m²).
      radial_target: the internal σ3 returned, a key of :data:`calibrate.datasets.RADIAL_TARGETS`.

    Returns:
      the record (SI: Pa, strains), the specimen (m, Pa) and the internal σ1 and σ3 (Pa) of the kept rows.
    """
    axial = np.asarray(rows["axial_strain"], dtype=np.float64)
    keep = np.concatenate([[True], np.diff(axial) > 0.0])
    keep &= np.maximum.accumulate(axial) == axial
    volumetric = np.asarray(rows["volumetric_strain"], dtype=np.float64)[keep]
    radial = np.asarray(rows["radial_strain"], dtype=np.float64)[keep]  # theory.radial_strain of the two
    axial = axial[keep]
    cell = np.full(axial.shape, 1e3 * config["cell_pressure_kpa"])
    record = lab.LabRecord(
        axial,
        volumetric,
        radial,
        np.asarray(rows["external_axial_stress"], dtype=np.float64)[keep],
        cell,
        ("synthetic: a membrax simulation",),
    )
    # A random member's solid fraction is a laboratory's void ratio (FCC members carry none: NaN).
    fraction = float(rows["solid_fraction"]) if "solid_fraction" in rows else math.nan
    # The height after consolidation, as a laboratory measures it (the first record is a step into shearing).
    height = None
    if "height" in rows:
        height = float(rows["height"][0]) / (1.0 - float(rows["axial_strain"][0]))
    specimen = correct.LabSpecimen(
        math.sqrt(4.0 * float(rows["platen_area"][0]) / math.pi),
        1e-3 * characteristic_size_mm(config),
        1e-3 * config["membrane_thickness_mm"],
        1e3 * config["membrane_modulus_kpa"],
        fraction if math.isfinite(fraction) else None,
        height if height is not None and math.isfinite(height) else None,
    )
    internal_1 = np.asarray(rows["internal_axial_stress"], dtype=np.float64)[keep]
    name = datasets.RADIAL_TARGETS[radial_target]
    if name not in rows:
        raise ValueError(
            f"the sweep records no {name!r}: score a correction whose radial_target is 'section_4_3', or run "
            "the sweep again with this membrax."
        )
    internal_3 = np.asarray(rows[name], dtype=np.float64)[keep]
    return record, specimen, internal_1, internal_3


def friction_angle_table(record, result, internal_1, internal_3, strains=correct.REPORT_STRAINS) -> str:
    """φ' (degrees) by method at the records nearest ``strains``, beside the internal φ', as a text table.

    Args:
      record: the corrected :class:`calibrate.lab.LabRecord` (strains dimensionless).
      result: :func:`calibrate.correct.correct_record`'s result for it.
      internal_1: the internal σ1 of each record (any stress unit).
      internal_3: the internal σ3 of each record, the same unit.
      strains: the axial strains to show, dimensionless (not %).
    """
    from membrax.triaxial.analysis import friction_angle_deg

    internal = friction_angle_deg(internal_1, internal_3)
    lines = [f"{'ε_a %':>6}{'internal':>10}" + "".join(f"{m:>16}" for m in correct.METHODS)]
    for target in strains:
        i = int(np.argmin(np.abs(record.axial_strain - target)))
        lines.append(
            f"{100 * record.axial_strain[i]:6.2f}{internal[i]:10.2f}"
            + "".join(f"{result.friction_angle[m][i]:16.2f}" for m in correct.METHODS)
        )
    return "\n".join(lines)


def friction_angle_errors(record, specimen, internal_1, internal_3, corrections=None, max_strain=0.10):
    """{method: (mean, worst) |φ' − φ'_internal|} in degrees over 0 < ε_a ≤ ``max_strain`` (module docstring).

    Records where the fitted correction is undefined (its strain-ratio window is short) are left out of
    every method, so all are scored on the same records.

    Args:
      record: a :class:`calibrate.lab.LabRecord` (Pa, strains).
      specimen: its :class:`calibrate.correct.LabSpecimen` (m, Pa).
      internal_1: the internal σ1 of each record, Pa.
      internal_3: the internal σ3 of each record, Pa.
      corrections: the fitted correction (default the shipped one).
      max_strain: the largest axial strain scored, dimensionless.
    """
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = correct.correct_record(record, specimen, corrections)
    from membrax.triaxial.analysis import friction_angle_deg

    internal = friction_angle_deg(internal_1, internal_3)
    strain = record.axial_strain
    rows = (strain > 0.0) & (strain <= max_strain + 1e-12) & np.isfinite(result.friction_angle["fitted"])
    errors = {}
    for method in correct.METHODS:
        error = np.abs(result.friction_angle[method][rows] - internal[rows])
        errors[method] = (float(np.mean(error)), float(np.max(error)))
    return errors


def held_out_errors(dataset, corrections=None, max_strain=0.10) -> dict:
    """Per member and pooled, the φ' errors of :func:`friction_angle_errors` for every member of a sweep.

    Each member's internal φ' is that of the correction's own radial target (its ``radial_target``).

    Returns:
      {"members": [(config fields, errors)], "pooled": {method: (mean of means, worst of worsts)}}.
    """
    corrections = correct.default_corrections() if corrections is None else corrections
    members = []
    for config, rows in datasets.sweep_members(dataset):
        record, specimen, internal_1, internal_3 = lab_record_of(config, rows, corrections.radial_target)
        errors = friction_angle_errors(record, specimen, internal_1, internal_3, corrections, max_strain)
        fields = {
            k: config[k] for k in ("cell_pressure_kpa", "membrane_thickness_mm", "membrane_modulus_kpa")
        }
        fields["particles_across"] = config["particles_across"]
        members.append((fields, errors))
    pooled = {
        method: (
            float(np.mean([e[method][0] for _, e in members])),
            float(np.max([e[method][1] for _, e in members])),
        )
        for method in correct.METHODS
    }
    return {"members": members, "pooled": pooled}


def element_errors(dataset, element: dict, corrections=None, max_strain=0.10) -> dict:
    """Each method's peak and late φ' against the internal ones and against the material's own (the element).

    Every member of a sweep is corrected by every method (:func:`calibrate.correct.correct_record`); its peak
    φ' (the largest over 0 < ε_a ≤ ``max_strain`` where the fitted correction is defined) and late φ'
    (:func:`membrax.triaxial.analysis.late_mean`) are compared with the internal φ' (the correction's own
    radial target) and with ``element``'s, the boundary-free periodic element of the same spheres, state and
    σc (:mod:`calibrate.size_effect`'s table).

    Args:
      dataset: a ``sweep.nc`` of membrane cells.
      element: {σc kPa: (peak φ', late φ')} of the periodic element, degrees.
      corrections: the fitted correction (default the shipped one).
      max_strain: the largest axial strain scored.

    Returns:
      {"members": [(fields, {method: {"peak_internal", "late_internal", "peak_element", "late_element"}})]}
      with signed errors φ'_method − φ'_target in degrees; members at a σc ``element`` lacks are left out.
    """
    import warnings

    from membrax.triaxial.analysis import friction_angle_deg, late_mean

    corrections = correct.default_corrections() if corrections is None else corrections
    members = []
    for config, rows in datasets.sweep_members(dataset):
        if config["cell_pressure_kpa"] not in element:
            continue
        record, specimen, internal_1, internal_3 = lab_record_of(config, rows, corrections.radial_target)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = correct.correct_record(record, specimen, corrections)
        strain = record.axial_strain
        scored = (
            (strain > 0.0) & (strain <= max_strain + 1e-12) & np.isfinite(result.friction_angle["fitted"])
        )
        internal = friction_angle_deg(internal_1, internal_3)[scored]
        element_peak, element_late = element[config["cell_pressure_kpa"]]
        targets = {
            "internal": (float(np.nanmax(internal)), late_mean(strain[scored], internal)),
            "element": (element_peak, element_late),
        }
        errors = {}
        for method in correct.METHODS:
            angle = result.friction_angle[method][scored]
            peak, late = float(np.nanmax(angle)), late_mean(strain[scored], angle)
            errors[method] = {
                f"{kind}_{target}": value - targets[target][k]
                for target in targets
                for k, (kind, value) in enumerate((("peak", peak), ("late", late)))
            }
        fields = {
            k: config[k] for k in ("cell_pressure_kpa", "membrane_thickness_mm", "membrane_modulus_kpa")
        }
        members.append((fields, errors))
    return {"members": members}


def specimen_words(config: dict, rows=None) -> str:
    """A member's specimen in words: the FCC lattice, or a random packing (its grading and state)."""
    if config.get("packing", "fcc") == "fcc":
        return f"FCC specimen of {config['particles_across']} spheres across, {config['layers']} layers"
    what = ("graded " if config.get("grading") else "") + datasets.grading_words(config)
    state = compaction_state(config.get("compaction_friction_deg", 0.0))
    words = f"random {state} packing of {what} spheres, seed {config.get('packing_seed', 0)}"
    if rows is not None and "solid_fraction" in rows:
        words += f", solid fraction {float(rows['solid_fraction']):.3f}"
    return words


#: The header of the four columns ``membrax correct`` reads, in the units :func:`write_lab_csv` writes.
LAB_CSV_HEADER = "axial_strain [%],volumetric_strain [%],deviator_stress [kPa],cell_pressure [kPa]"


def write_lab_csv(path, axial_strain, volumetric_strain, deviator_stress, cell_pressure, fmt="%.8g") -> Path:
    """Write a laboratory record's four columns (SI: strains, Pa) as a CSV in % and kPa (LAB_CSV_HEADER)."""
    path = Path(path)
    table = np.stack(
        [100 * np.asarray(axial_strain), 100 * np.asarray(volumetric_strain)]
        + [
            1e-3 * np.broadcast_to(np.asarray(x, float), np.shape(axial_strain))
            for x in (deviator_stress, cell_pressure)
        ],
        axis=1,
    )
    np.savetxt(path, table, delimiter=",", header=LAB_CSV_HEADER, comments="", fmt=fmt)
    return path


def write_resampled_record(record, rows: int, path) -> Path:
    """``record`` (a :class:`calibrate.lab.LabRecord`) on ``rows`` equally spaced axial strains, as a CSV.

    The record's columns interpolated linearly and written by :func:`write_lab_csv`: the same test read more
    (or less) densely.
    """
    strain = np.linspace(record.axial_strain[0], record.axial_strain[-1], rows)

    def at(values):
        return np.interp(strain, record.axial_strain, values)

    deviator = at(record.axial_stress - record.cell_pressure)
    return write_lab_csv(path, strain, at(record.volumetric_strain), deviator, at(record.cell_pressure))


def write_example_record(
    dataset, path, version: str, source: str = "calibrate.designs.RANDOM_HELD_OUT", **coordinates
) -> Path:
    """Write the member of ``dataset`` at ``coordinates`` as a laboratory-style CSV (module docstring).

    ``source`` names the design the member comes from (e.g. ``calibrate.designs.RANDOM_HELD_OUT``).
    """
    chosen = [
        (config, rows)
        for config, rows in datasets.sweep_members(dataset)
        if all(math.isclose(config[k], v) for k, v in coordinates.items())
    ]
    if not chosen:
        raise ValueError(f"no member of the sweep at {coordinates}.")
    return write_member_record(*chosen[0], path, version, source)


def write_member_record(config: dict, rows, path, version: str, source: str) -> Path:
    """Write one sweep member (:func:`datasets.sweep_members`) as a laboratory-style CSV (module docstring).

    Columns: what ``membrax correct`` reads (ε_a, ε_v in %, q and σc in kPa) and, which it does not read,
    the internal σ1 and the §4.3 σ3 (``internal_sigma_1``, ``internal_sigma_3``) and, where the sweep
    records it, the received σ3 (``internal_sigma_3_received``), in kPa.
    """
    from membrax.io.files import atomic_write_bytes

    record, specimen, internal_1, internal_3 = lab_record_of(config, rows)
    received = None
    if datasets.RADIAL_TARGETS["received"] in rows:
        received = lab_record_of(config, rows, "received")[3]
    particle = round(characteristic_size_mm(config), 2)
    arguments = (
        round(1e3 * specimen.specimen_diameter, 1),
        particle,
        config["membrane_thickness_mm"],
        config["membrane_modulus_kpa"],
    )
    out = io.StringIO()
    out.write(
        f"# synthetic: produced by a membrax {version} simulation ({source}), not a laboratory test\n"
        f"# {specimen_words(config, rows)}: specimen diameter {1e3 * specimen.specimen_diameter:.1f} mm, "
        f"particle size {particle:g} mm; membrane {config['membrane_thickness_mm']:g} mm of "
        f"{config['membrane_modulus_kpa']:g} kPa; cell pressure {config['cell_pressure_kpa']:g} kPa\n"
        "# internal_sigma_1/internal_sigma_3: the stresses the specimen carried (membrax's internal stresses,"
        " the paper's 4.3); internal_sigma_3_received (where given): the radial load the specimen received"
        " over the membrane's projected area; membrax correct does not read them\n"
        f"# {EXAMPLE_ARGUMENTS_PREFIX} "
        + " ".join(f"{flag} {value:g}" for flag, value in zip(SPECIMEN_FLAGS, arguments, strict=True))
        + (
            ""
            if specimen.solid_fraction is None
            else f" {VOID_RATIO_FLAG} {round(1.0 / specimen.solid_fraction - 1.0, 3):g}"
        )
        + ("" if specimen.height is None else f" {HEIGHT_FLAG} {round(1e3 * specimen.height, 1):g}")
        + "\n"
    )
    columns = {
        "axial_strain [%]": 100.0 * record.axial_strain,
        "volumetric_strain [%]": 100.0 * record.volumetric_strain,
        "deviator_stress [kPa]": 1e-3 * (record.axial_stress - record.cell_pressure),
        "cell_pressure [kPa]": 1e-3 * record.cell_pressure,
        f"{INTERNAL_COLUMNS['sigma_1']} [kPa]": 1e-3 * internal_1,
        f"{INTERNAL_COLUMNS['section_4_3']} [kPa]": 1e-3 * internal_3,
    }
    if received is not None:
        columns[f"{INTERNAL_COLUMNS['received']} [kPa]"] = 1e-3 * received
    out.write(",".join(columns) + "\n")
    table = np.stack(list(columns.values()), axis=1)
    np.savetxt(out, table, delimiter=",", fmt="%.7g")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, out.getvalue().encode())
    return path


def corrected_csv_errors(record_path, corrected_path, radial_target: str, max_strain: float = 0.10) -> dict:
    """φ' errors of a ``membrax correct`` output against a member record's internal φ', per radial target.

    The user's route: :func:`write_member_record` wrote the record, ``membrax correct`` corrected it from
    its external columns alone; here each method's φ' (the output's ``friction_angle_<method>``) is compared
    with φ'_internal = arcsin((σ1 − σ3)/(σ1 + σ3)) of the record's internal columns, for each radial target
    the record has. The ``fitted`` method is the correction's own for its ``radial_target`` and its
    alternate's (``friction_angle_fitted_<target>``) for the other, where the output has it. Rows scored:
    0 < ε_a ≤ ``max_strain`` where that target's fitted φ' is defined.

    Args:
      record_path: the member record (CSV of :func:`write_member_record`).
      corrected_path: ``membrax correct``'s CSV for it.
      radial_target: the correction's radial target (:data:`calibrate.datasets.RADIAL_TARGETS`).
      max_strain: the largest axial strain scored, dimensionless.

    Returns:
      {target: {method: (mean, worst) |φ' − φ'_internal| in degrees}} for each target the record and the
      output both carry.

    Raises:
      ValueError: the two files have different numbers of readings or axial strains.
    """
    from membrax.triaxial.analysis import friction_angle_deg

    record = csv_columns(record_path)
    corrected = csv_columns(corrected_path)
    strain = 1e-2 * corrected["axial_strain"]
    if strain.shape != record["axial_strain"].shape or not np.allclose(
        strain, 1e-2 * record["axial_strain"], rtol=1e-6, atol=1e-12
    ):
        raise ValueError(
            f"{corrected_path} does not have the readings of {record_path} (rows or axial strains differ)."
        )
    sigma_1 = record[INTERNAL_COLUMNS["sigma_1"]]
    errors = {}
    for target in datasets.RADIAL_TARGETS:
        fitted = "friction_angle_fitted" + ("" if target == radial_target else f"_{target}")
        if INTERNAL_COLUMNS[target] not in record or fitted not in corrected:
            continue
        internal = friction_angle_deg(sigma_1, record[INTERNAL_COLUMNS[target]])
        angles = {m: corrected[f"friction_angle_{m}"] for m in correct.METHODS if m != "fitted"}
        angles["fitted"] = corrected[fitted]
        rows = (strain > 0.0) & (strain <= max_strain + 1e-12) & np.isfinite(angles["fitted"])
        if not np.any(rows):
            continue
        errors[target] = {
            m: (
                float(np.mean(np.abs(a[rows] - internal[rows]))),
                float(np.max(np.abs(a[rows] - internal[rows]))),
            )
            for m, a in angles.items()
        }
    return errors


def csv_columns(path) -> dict:
    """{name without its [unit]: column} of a comma-separated table with ``#`` comment lines."""
    lines = [line for line in Path(path).read_text().splitlines() if line and not line.startswith("#")]
    names = [cell.split("[")[0].strip() for cell in lines[0].split(",")]
    table = np.loadtxt(lines[1:], delimiter=",", ndmin=2)
    return {name: table[:, i] for i, name in enumerate(names)}
