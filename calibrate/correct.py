"""Membrane corrections applied to a laboratory record: none, the classical three and the fitted one.

Contract. :func:`correct_record` takes a :class:`calibrate.lab.LabRecord` (SI), the :class:`LabSpecimen`
(diameter after consolidation D_s, particle size D, membrane thickness t_m and modulus E_m; optionally
the void ratio and the height H after consolidation) and a fitted
correction (:class:`calibrate.persistence.Corrections`; default :func:`default_corrections`, shipped with
the package) and returns a :class:`CorrectedRecord`: σ1, σ3 and the mobilised φ' by each method, with the
fitted method's standard deviation, and the warnings for inputs outside the fitted range. Methods
(:data:`METHODS`):

- ``uncorrected``: σ1 the measured axial stress, σ3 the cell pressure;
- ``astm``: ASTM D4767/D7181, σ1 − 4 E_m t_m ε_a/D_s (:func:`membrax.theory.astm_shell_correction`);
- ``henkel_gilbert``: Henkel & Gilbert's hoop tension, σ3 + 2 E_m t_m ε_θ/D with ε_θ from ε_v
  (:func:`membrax.theory.hoop_tension_correction`, clipped at 0 where the hoop would buckle);
- ``kuerbis_vaid``: a thin elastic shell bonded to the right cylinder, ν = 0.5 (Kuerbis & Vaid 1990;
  :func:`membrax.theory.right_cylinder_shell_correction`);
- ``fitted``: the DEM-based correction, σ1 + σc·Δσ_a/σc and σc + σc·Δσ_r/σc with the fitted model
  (:mod:`calibrate.models`) on the record's inputs (:func:`calibrate.datasets.measured_inputs`). The
  classical corrections say what the membrane *takes* from the measured stresses; membrax's extra
  stresses are internal − external (the specimen carries more than the cell and ram apply), hence the
  opposite signs of the two families.

Uncertainty of the fitted method (one standard deviation), per record: the parameters' covariance
propagated by the delta method, var = g C gᵀ with g = ∂prediction/∂θ (``jax.jacfwd``), plus the model's
prediction error on cases it was not fitted on, the leave-one-case-out RMS of ``membrax fit`` (stored in
the JSON; the fit's RMS residual if there was no cross-validation), added in quadrature. For φ' it is
propagated through sin φ' = (σ1 − σ3)/(σ1 + σ3), the axial and radial errors taken as independent.

Outside the fitted range. The record's dimensionless groups and strains (:data:`CHECKED_INPUTS`) are
checked against the ranges of the table the correction was fitted on; each one outside is warned about in
a laboratory's words (:data:`QUANTITY_WORDS`), with its value and the fitted range. The band there is not
the in-range one: with δ the largest distance outside a range, per row, in units of that range's width
(in logarithms for the ratios of sizes and stiffnesses, :data:`LOG_DISTANCE`), the standard deviation is
multiplied by 1 + δ (it doubles one range's width outside), and beyond δ = :data:`MAX_EXTRAPOLATION` the
fitted method is withheld (NaN): a linear model carried further than the span it was fitted on is a guess.
The specimen is also checked against the packing family the correction was fitted on (its JSON's
``packing_family``, :func:`family_warnings`): a correction fitted on FCC lattices alone is warned about, and
so is a void ratio (``LabSpecimen.solid_fraction``) outside the fitted members' range, which also widens the
band and withholds like the inputs above, its distance in units of the fitted span of void ratios
(:func:`void_ratio_distance`).

Specimen height. The correction records the H/D_s of the specimens it was fitted on (1.99–2.50 for the
shipped one, the 2–2.5 laboratories test at: ASTM D7181, BS 1377-8; 1.28–1.67 for the random grid's). A record
whose height is not given is warned about (:func:`aspect_ratio_warnings`); one whose H/D_s lies outside is
warned about like the other quantities and its band widened by the same 1 + δ (in logarithms), but the fitted
column is not withheld for it. The withholding is for a model carried beyond the span of the inputs it reads;
no model reads H/D_s, so its distance says how far an untested assumption (the extra stresses per unit area do
not depend on the height) is carried, an uncertainty rather than an extrapolated term. And H/D_s spans a
factor of 1.3 only, so one width in logarithms is H/D_s = 2.2: withholding there would withhold the correction
on most standard tests, though on the paper-size random members (moulds of H/D_s = 2) it halved the
uncorrected error (docs/calibration.md).

Abstention (:mod:`calibrate.abstention`). A correction fitted with a rule carries, per region of
E_m t_m/(σc D), a factor w in [0, 1] for each of its σ1 and σ3 corrections, chosen on the
cross-validated predictions so that there the scaled correction erred no more than none on unseen cases.
The record's region (of its median E_m t_m/(σc D)) gives the factors, applied to the whole record; where
a factor is below 1 the fitted prediction and its parameter uncertainty are scaled by it, the prediction
error in the band is the region's error of the chosen factor on unseen cases (its ``rms``), a warning says
so, and the CSV carries the factors (``fitted_shrink_axial``, ``fitted_shrink_radial``). A correction
without a rule never abstains.

Radial target. The fitted σ3 reproduces the correction's ``radial_target``
(:data:`calibrate.datasets.RADIAL_TARGETS`, docs/model.md): the received stress (the radial load the
spheres and clamps receive over the membrane's radially projected area, equal to σc when the membrane
carries nothing) for a correction fitted since that choice, the shipped one included, and the paper's §4.3
stress for files written before. A correction with an ``alternate`` (the same fit with the other target) gives
that one's fitted σ1, σ3, φ' and φ' band beside (:mod:`calibrate.report` writes them, in the columns
``*_fitted_<target>``).

The CSV, the plot, the output paths and the ``membrax correct`` command are :mod:`calibrate.report`'s.
"""

from __future__ import annotations

import functools
import math
import numbers
import warnings
from importlib import resources
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from calibrate import abstention, datasets, models, persistence

__all__ = [
    "METHODS",
    "REPORT_STRAINS",
    "abstention_warning",
    "aspect_ratio_warnings",
    "CorrectedRecord",
    "LabSpecimen",
    "correct_record",
    "default_corrections",
    "family_warnings",
    "example_record_path",
    "extrapolation_distances",
    "range_warnings",
]

#: The axial strains (fractions) φ' is reported at: the terminal, a series' table, the scorer's table.
REPORT_STRAINS = (0.01, 0.02, 0.05, 0.10)
#: The methods, in the order of the CSV's columns and the plot's legend.
METHODS = ("uncorrected", "astm", "henkel_gilbert", "kuerbis_vaid", "fitted")
LABELS = {
    "uncorrected": "uncorrected",
    "astm": "ASTM D4767/D7181 shell",
    "henkel_gilbert": "Henkel & Gilbert hoop",
    "kuerbis_vaid": "Kuerbis & Vaid shell",
    "fitted": "fitted (membrax DEM)",
}
#: Inputs whose fitted range a record is checked against (the dimensionless groups and the strains).
CHECKED_INPUTS = persistence.RANGE_INPUTS
#: The specimen's height over diameter H/D_s: checked against its fitted range when the height is given;
#: it widens the band but does not withhold the fitted column (module docstring).
ASPECT_RATIO = persistence.ASPECT_RATIO
#: H/D_s outside these bounds is refused as a mistyped height (a triaxial specimen is 1-3 diameters tall).
ASPECT_RATIO_BOUNDS = (0.5, 5.0)
#: The height/diameter ratio laboratories test at (ASTM D7181 and BS 1377-8: 2 to 2.5).
STANDARD_ASPECT_RATIO = (2.0, 2.5)
DEFAULT_MODEL_FILE = "default_corrections.json"
EXAMPLE_RECORD_FILE = "example_record.csv"
#: The example values the specimen's errors suggest (a 150 mm ballast test, the paper's latex).
SPECIMEN_EXAMPLES = {
    "specimen_diameter_mm": 150.0,
    "particle_size_mm": 20.0,
    "membrane_thickness_mm": 2.0,
    "membrane_modulus_kpa": 1400.0,
    "specimen_height_mm": 300.0,
}
#: A membrane modulus below this many kPa is refused as MPa written as kPa (latex is about 1400 kPa).
SMALLEST_MEMBRANE_MODULUS_KPA = 10.0
#: The checked quantities in a laboratory's words: (words, symbol, display scale, display unit).
QUANTITY_WORDS = {
    "axial_strain": ("axial strain", "ε_a", 100.0, " %"),
    "thickness_ratio": ("membrane thickness / particle size", "t_m/D", 1.0, ""),
    "stiffness_ratio": ("membrane stiffness / (cell pressure × particle size)", "E_m t_m/(σc D)", 1.0, ""),
    "size_ratio": ("particle size / specimen diameter", "D/D_s", 1.0, ""),
    "indentation_ratio": ("membrane indentation / particle size (Molenkamp & Luger)", "α/D", 1.0, ""),
    "hoop_ratio": ("hoop stress / cell pressure (Henkel & Gilbert)", "2E_m t_m ε_θ/(D_s σc)", 1.0, ""),
    "strain_ratio_change": ("radial / axial strain increment", "dε_r/dε_a", 1.0, ""),
    ASPECT_RATIO: ("specimen height / diameter", "H/D_s", 1.0, ""),
}
#: Quantities whose distance outside the fitted range is counted in logarithms: positive ratios of sizes
#: and stiffnesses, whose fitted ranges span factors (1.3 for H/D_s, 1.75 for D/D_s to 67 for
#: E_m t_m/(σc D)). The strains and the hoop ratio, which start at or cross zero, are counted linearly.
LOG_DISTANCE = ("thickness_ratio", "stiffness_ratio", "size_ratio", "indentation_ratio", ASPECT_RATIO)
#: Beyond this distance outside the fitted range (in the range's widths) the fitted correction is withheld.
MAX_EXTRAPOLATION = 1.0


class LabSpecimen(NamedTuple):
    """What a laboratory knows of its test, in SI units (m, Pa).

    Attributes:
      specimen_diameter: D_s after consolidation, > 0.
      particle_diameter: D, the characteristic particle size (e.g. d50), > 0.
      membrane_thickness: t_m, > 0.
      membrane_modulus: E_m, > 0.
      solid_fraction: the specimen's solid fraction 1/(1 + e) after consolidation, or None when not
        known (it is checked against the correction's packing family, :func:`family_warnings`).
      height: H after consolidation, or None when not known (H/D_s is checked against the heights the
        correction was fitted on, :func:`aspect_ratio_warnings`).
    """

    specimen_diameter: float
    particle_diameter: float
    membrane_thickness: float
    membrane_modulus: float
    solid_fraction: float | None = None
    height: float | None = None

    @classmethod
    def from_mm_kpa(
        cls,
        specimen_diameter_mm,
        particle_size_mm,
        membrane_thickness_mm,
        membrane_modulus_kpa,
        void_ratio=None,
        specimen_height_mm=None,
    ):
        """A specimen from the user-facing units, each checked to be a positive finite number.

        ``void_ratio`` e (optional, the laboratory's measure of density) is stored as the solid fraction
        1/(1 + e); ``specimen_height_mm`` (optional) as the height in m.

        Raises:
          ValueError: a value that is not a positive finite number, a particle size not below the specimen
            diameter, a membrane thicker than a quarter of the diameter, a modulus below
            :data:`SMALLEST_MEMBRANE_MODULUS_KPA` (MPa written as kPa), a void ratio outside 0.1–3 (a
            porosity or a percentage given for it), or a height outside :data:`ASPECT_RATIO_BOUNDS`
            diameters (a radius, or cm, given for it), each named with an example.
        """
        if void_ratio is not None and not (
            isinstance(void_ratio, numbers.Real) and np.isfinite(void_ratio) and 0.1 <= void_ratio <= 3.0
        ):
            raise ValueError(
                f"void_ratio = {void_ratio!r}; give the void ratio e = V_voids/V_solids, between 0.1 and 3 "
                "(ballast is about 0.6-0.8: --void-ratio 0.7; a porosity n converts as e = n/(1 - n))."
            )
        values = {
            "specimen_diameter_mm": specimen_diameter_mm,
            "particle_size_mm": particle_size_mm,
            "membrane_thickness_mm": membrane_thickness_mm,
            "membrane_modulus_kpa": membrane_modulus_kpa,
        }
        if specimen_height_mm is not None:
            values["specimen_height_mm"] = specimen_height_mm
        for name, value in values.items():
            if not (isinstance(value, numbers.Real) and np.isfinite(value) and value > 0):
                raise ValueError(
                    f"{name} = {value!r}; give a positive number "
                    f"(e.g. --{name.replace('_', '-')} {SPECIMEN_EXAMPLES[name]:g})."
                )
        if particle_size_mm >= specimen_diameter_mm:
            raise ValueError(
                f"particle_size_mm = {particle_size_mm:g} is not below specimen_diameter_mm = "
                f"{specimen_diameter_mm:g}; give both in mm (the particle size is d50)."
            )
        if 4.0 * membrane_thickness_mm >= specimen_diameter_mm:
            raise ValueError(
                f"membrane_thickness_mm = {membrane_thickness_mm:g} is a quarter or more of "
                f"specimen_diameter_mm = {specimen_diameter_mm:g}; give both in mm (a membrane is 0.3-5 mm)."
            )
        if membrane_modulus_kpa < SMALLEST_MEMBRANE_MODULUS_KPA:
            raise ValueError(
                f"membrane_modulus_kpa = {membrane_modulus_kpa:g}: no membrane is that soft; is it in MPa? "
                f"Give it in kPa (latex is about 1400 kPa: --membrane-modulus-kpa 1400)."
            )
        if specimen_height_mm is not None:
            ratio = specimen_height_mm / specimen_diameter_mm
            low, high = ASPECT_RATIO_BOUNDS
            if not low <= ratio <= high:
                raise ValueError(
                    f"specimen_height_mm = {specimen_height_mm:g} is {ratio:.3g} × specimen_diameter_mm = "
                    f"{specimen_diameter_mm:g}; a triaxial specimen is {low:g} to {high:g} diameters tall "
                    f"(ASTM D7181 and BS 1377-8: {STANDARD_ASPECT_RATIO[0]:g}-{STANDARD_ASPECT_RATIO[1]:g}). "
                    "Give the height after consolidation in mm, the same unit as the diameter "
                    f"(e.g. --specimen-height-mm {STANDARD_ASPECT_RATIO[0] * specimen_diameter_mm:g})."
                )
        return cls(
            1e-3 * specimen_diameter_mm,
            1e-3 * particle_size_mm,
            1e-3 * membrane_thickness_mm,
            1e3 * membrane_modulus_kpa,
            None if void_ratio is None else 1.0 / (1.0 + float(void_ratio)),
            None if specimen_height_mm is None else 1e-3 * specimen_height_mm,
        )


class CorrectedRecord(NamedTuple):
    """σ1, σ3 (Pa) and φ' (degrees) by each method of :data:`METHODS` (module docstring).

    Attributes:
      record: the :class:`calibrate.lab.LabRecord` corrected.
      sigma_1, sigma_3, friction_angle: {method: array over the rows}.
      std: {"sigma_1", "sigma_3", "friction_angle": array}, the fitted method's standard deviation.
      inputs: the fitted model's input columns (:func:`calibrate.datasets.measured_inputs`).
      warnings: messages for inputs outside the fitted range.
      extrapolation: δ per row, the largest distance outside the fitted range
        (:func:`extrapolation_distances`); the band is widened by 1 + δ and the fitted method withheld
        (NaN) where δ > :data:`MAX_EXTRAPOLATION` (H/D_s aside: it widens, never withholds).
      shrink: (w for σ1, w for σ3), the factors the abstention rule scaled the fitted correction by
        (:mod:`calibrate.abstention`; 1 without a rule).
      radial_target: the internal radial stress the fitted σ3 reproduces
        (:data:`calibrate.datasets.RADIAL_TARGETS`).
      alternate: the record corrected by the correction's ``alternate`` (the other radial target), or
        None when it has none.
    """

    record: object
    sigma_1: dict
    sigma_3: dict
    friction_angle: dict
    std: dict
    inputs: dict
    warnings: tuple
    extrapolation: np.ndarray
    shrink: tuple = (1.0, 1.0)
    radial_target: str = datasets.LEGACY_RADIAL_TARGET
    alternate: CorrectedRecord | None = None


def default_corrections() -> persistence.Corrections:
    """The correction shipped with the package (fitted on :data:`calibrate.designs.LAB_CALIBRATION`)."""
    with resources.as_file(resources.files("calibrate") / "data" / DEFAULT_MODEL_FILE) as path:
        return persistence.load_corrections(path)


def example_record_path():
    """A context manager giving the shipped synthetic example record's path (``importlib.resources``)."""
    return resources.as_file(resources.files("calibrate") / "data" / EXAMPLE_RECORD_FILE)


def _prediction_rms(corrections) -> tuple[float, float]:
    """The model's RMS error on unseen cases (axial, radial), in Δσ/σc (module docstring)."""
    scores = corrections.provenance.get("cross_validation")
    if scores:
        axial = np.asarray(scores["axial_rms"], dtype=np.float64)
        radial = np.asarray(scores["radial_rms"], dtype=np.float64)
        return float(np.sqrt(np.mean(axial**2))), float(np.sqrt(np.mean(radial**2)))
    return corrections.rms, corrections.rms


def extrapolation_distances(inputs: dict, input_ranges: dict) -> dict:
    """Each checked input's distance outside its fitted range, per row, in units of the range's width.

    δ = max(0, (low − x)/(high − low), (x − high)/(high − low)), with x, low and high replaced by their
    logarithms for :data:`LOG_DISTANCE`; 0 inside the range and where x is undefined (NaN). A range of zero
    width gives infinity outside it.

    Args:
      inputs: the record's input columns (:func:`calibrate.datasets.measured_inputs`), and
        :data:`ASPECT_RATIO` when the specimen's height is known.
      input_ranges: {name: (low, high)} of the fitted table (:class:`calibrate.persistence.Corrections`).

    Returns:
      {name: float64 array over the rows} for each of :data:`CHECKED_INPUTS` and :data:`ASPECT_RATIO` in
      ``inputs`` with a known range.
    """
    distances = {}
    for name in (*CHECKED_INPUTS, ASPECT_RATIO):
        if name not in inputs or name not in input_ranges or None in input_ranges[name]:
            continue
        low, high = (float(v) for v in input_ranges[name])
        values = np.asarray(inputs[name], dtype=np.float64)
        # Ranges are stored from float32 tables: a record on the bound is inside it.
        low, high = low - 1e-12 * abs(low), high + 1e-12 * abs(high)
        with np.errstate(divide="ignore", invalid="ignore"):
            if name in LOG_DISTANCE and low > 0.0:
                values = np.log(np.where(values > 0.0, values, np.nan))
                low, high = np.log(low), np.log(high)
            outside = np.maximum(np.maximum(low - values, values - high), 0.0)
            width = high - low
            distance = outside / width if width > 0.0 else np.where(outside > 0.0, np.inf, 0.0)
        distances[name] = np.where(np.isnan(values), 0.0, distance)
    return distances


def range_warnings(inputs: dict, input_ranges: dict, distances: dict | None = None) -> list[str]:
    """A message in a laboratory's words for each checked input outside the correction's fitted range.

    Each names the quantity, its symbol, the record's value (or span) and the fitted range, in the units a
    laboratory reads (the axial strain in %), and the distance outside the range
    (:func:`extrapolation_distances`; pass them when already computed).
    """
    messages = []
    distances = extrapolation_distances(inputs, input_ranges) if distances is None else distances
    for name, distance in distances.items():
        if not np.any(distance > 0.0):
            continue
        words, symbol, scale, unit = QUANTITY_WORDS[name]
        low, high = (scale * float(v) for v in input_ranges[name])
        values = scale * np.asarray(inputs[name], dtype=np.float64)
        values = values[np.isfinite(values)]
        first, last = values.min(), values.max()
        if np.isclose(first, last, rtol=1e-9):
            value = f"= {first:.3g}{unit}"
        else:
            value = f"spans {first:.3g} to {last:.3g}{unit}"
        scaled = " in logarithms" if name in LOG_DISTANCE else ""
        rows = int(np.sum(distance > 0.0))
        messages.append(
            f"{words}, {symbol}, {value}; the correction was fitted on {low:.3g} to {high:.3g}{unit} "
            f"({rows} of {distance.size} rows outside it, by up to {np.max(distance):.2g} of that range's "
            f"width{scaled})."
        )
    return messages


def family_warnings(specimen: LabSpecimen, packing_family: dict | None) -> list[str]:
    """Messages for a specimen outside the packing family a correction was fitted on (module docstring).

    A correction fitted on FCC lattices only is warned about for every laboratory specimen (a random
    packing, on which such a correction scored worse than no correction: docs/calibration.md); a specimen
    whose solid fraction (from ``--void-ratio``) lies outside the random members' range is warned about
    with both in void ratios. A correction without a recorded family (written before it existed) gives none.
    """
    if not packing_family:
        return []
    messages = []
    if "random" not in packing_family.get("packings", ()):
        messages.append(
            "the correction was fitted on FCC lattices only; a laboratory specimen is a random packing, on "
            "which FCC-fitted corrections scored worse than no correction (docs/calibration.md): use the "
            "shipped correction (fitted on random packings) or fit one on specimens like yours."
        )
    fraction, span = specimen.solid_fraction, packing_family.get("solid_fraction")
    if fraction is not None and span and not (span[0] <= fraction <= span[1]):
        low_e, high_e = 1.0 / span[1] - 1.0, 1.0 / span[0] - 1.0
        messages.append(
            f"void ratio e = {1.0 / fraction - 1.0:.3g} (solid fraction {fraction:.3f}); the correction was "
            f"fitted on random packings of e = {low_e:.3g} to {high_e:.3g} (solid fraction {span[0]:.3f} to "
            f"{span[1]:.3f}; {', '.join(packing_family.get('states', ()))}): a "
            f"{'denser' if fraction > span[1] else 'looser'} specimen than any it has seen."
        )
    return messages


def void_ratio_distance(specimen: LabSpecimen, packing_family: dict | None) -> float:
    """The specimen's void ratio's distance outside the fitted members', in units of their span (0 inside).

    δ = max(0, e_low − e, e − e_high)/(e_high − e_low), e = 1/φ − 1 from the solid fraction φ; 0 when the
    void ratio or the fitted span is not known. It widens the band and withholds the fitted correction like
    the model's inputs (:func:`extrapolation_distances`).
    """
    span = (packing_family or {}).get("solid_fraction")
    if specimen.solid_fraction is None or not span:
        return 0.0
    void_ratio = 1.0 / specimen.solid_fraction - 1.0
    low, high = 1.0 / span[1] - 1.0, 1.0 / span[0] - 1.0
    if high <= low:
        return math.inf if not math.isclose(void_ratio, low) else 0.0
    return max(0.0, low - void_ratio, void_ratio - high) / (high - low)


def aspect_ratio_warnings(specimen: LabSpecimen, input_ranges: dict) -> list[str]:
    """A message when the specimen's height is not given though the correction records its fitted H/D_s.

    A height that is given is checked like the other quantities (:func:`range_warnings`); a correction
    written before heights were recorded gives no message either way (nothing to check against).
    """
    span = input_ranges.get(ASPECT_RATIO)
    if specimen.height is not None or not span or None in span:
        return []
    low, high = STANDARD_ASPECT_RATIO
    return [
        f"specimen height not given (--specimen-height-mm): the correction was fitted on specimens of "
        f"height / diameter H/D_s = {span[0]:.3g} to {span[1]:.3g}, and laboratories test at H/D {low:g} to "
        f"{high:g} (ASTM D7181, BS 1377-8), outside it. Give the height after consolidation to have it "
        "checked and the band widened for it."
    ]


def abstention_warning(stiffness_ratio: float, region: dict, shrink: tuple) -> str:
    """The message for a record whose fitted correction the abstention rule shrinks (module docstring)."""
    parts = []
    for symbol, target, weight in (("σ1", "axial", shrink[0]), ("σ3", "radial", shrink[1])):
        if weight >= 1.0:
            continue
        scores = region[target]
        action = "withdrawn (×0)" if weight == 0.0 else f"scaled by {weight:.2f}"
        parts.append(
            f"its {symbol} correction is {action}: on leave-one-case-out cross-validation of the "
            f"{region['cases']} simulated tests there, its error in {symbol}/σc was "
            f"{scores['fitted_rms']:.3f} RMS, against {scores['none_rms']:.3f} for no correction and "
            f"{scores['held_out_rms']:.3f} shrunk by the least-squares factor {scores['shrinkage']:.2f}; the "
            f"band takes the error of what is given, {scores['rms']:.3f}"
        )
    where = f"E_m t_m/(σc D) = {stiffness_ratio:.3g} lies in {region['low']:g} to {region['high']:g}"
    return (
        f"the fitted correction abstains in part: {where}, where {'; '.join(parts)}. The factors are in "
        "the CSV (fitted_shrink_axial, fitted_shrink_radial); the rule is in docs/calibration.md, "
        "'When the correction abstains'."
    )


def strain_ratio_window(axial_strain) -> float:
    """The strain window of dε_r/dε_a for a record: the sweeps' 0.5 %, or 4 readings where they are sparser.

    :func:`membrax.triaxial.analysis.strain_ratio_change` needs 3 records in the window; a laboratory
    logging every 0.25 % or more would leave most windows of 0.5 % with 2 and the correction undefined.
    Four median spacings put 3 records in the window at the record's ends and 5 inside.

    Args:
      axial_strain: the record's axial strains, dimensionless (not %).

    Returns:
      the window, as an axial strain (dimensionless).
    """
    from membrax.triaxial.analysis import STRAIN_RATIO_WINDOW

    spacing = np.diff(np.asarray(axial_strain, dtype=np.float64))
    return max(STRAIN_RATIO_WINDOW, 4.0 * float(np.median(spacing)) if spacing.size else 0.0)


@functools.lru_cache(maxsize=8)
def _corrections_fn(model_name: str, names: tuple):
    """The jitted corrections of a model of :data:`calibrate.models.MODELS`: σ1, σ3, φ' by method, std."""
    from membrax import theory

    model = models.MODELS[model_name]

    angle = theory.mobilised_friction_angle_deg  # unchecked on tracers

    def corrections(theta, covariance, inputs, axial, volumetric, measured, cell, membrane, rms, shrink):
        modulus, thickness, diameter = membrane[0], membrane[1], membrane[2]
        classical = {
            "astm": theory.astm_shell_correction(modulus, thickness, diameter, axial),
            "henkel_gilbert": theory.hoop_tension_correction(modulus, thickness, diameter, axial, volumetric),
            "kuerbis_vaid": theory.right_cylinder_shell_correction(
                modulus, thickness, diameter, axial, volumetric
            ),
        }
        sigma_1 = {"uncorrected": measured}
        sigma_3 = {"uncorrected": cell}
        for name, correction in classical.items():
            sigma_1[name], sigma_3[name] = theory.apply_membrane_correction(measured, cell, correction)

        def predict(flat):
            # The abstention rule's factors scale the prediction, and with it its parameter uncertainty.
            return shrink[:, None] * jnp.stack(model.predict(dict(zip(names, flat, strict=True)), inputs))

        prediction = predict(theta)  # (2, rows): Δσ_a/σc, Δσ_r/σc
        jacobian = jax.jacfwd(predict)(theta)  # (2, rows, p)
        parameter_var = jnp.einsum("krp,pq,krq->kr", jacobian, covariance, jacobian)
        std_axial = cell * jnp.sqrt(parameter_var[0] + rms[0] ** 2)
        std_radial = cell * jnp.sqrt(parameter_var[1] + rms[1] ** 2)
        sigma_1["fitted"] = measured + cell * prediction[0]
        sigma_3["fitted"] = cell + cell * prediction[1]
        friction = {m: angle(sigma_1[m], sigma_3[m]) for m in METHODS}
        d1, d3 = jax.vmap(jax.grad(angle, argnums=(0, 1)))(sigma_1["fitted"], sigma_3["fitted"])
        std = {
            "sigma_1": std_axial,
            "sigma_3": std_radial,
            "friction_angle": jnp.sqrt((d1 * std_axial) ** 2 + (d3 * std_radial) ** 2),
        }
        return sigma_1, sigma_3, friction, std

    return jax.jit(corrections)


def correct_record(record, specimen: LabSpecimen, corrections=None) -> CorrectedRecord:
    """Apply every method of :data:`METHODS` to ``record`` (module docstring).

    Args:
      record: a :class:`calibrate.lab.LabRecord`.
      specimen: the :class:`LabSpecimen`.
      corrections: a :class:`calibrate.persistence.Corrections` (default :func:`default_corrections`).

    Returns:
      A :class:`CorrectedRecord`: per method σ1, σ3 (Pa) and φ' (degrees), with the fitted method's
      standard deviations.
    """
    from membrax.triaxial.analysis import strain_ratio_change

    corrections = default_corrections() if corrections is None else corrections
    cell = np.asarray(record.cell_pressure, dtype=np.float64)
    measured = np.asarray(record.axial_stress, dtype=np.float64)
    inputs = datasets.measured_inputs(
        axial_strain=record.axial_strain,
        radial_strain=record.radial_strain,
        strain_ratio_change=strain_ratio_change(
            record.axial_strain, record.radial_strain, strain_ratio_window(record.axial_strain)
        ),
        cell_pressure=cell,
        membrane_thickness=specimen.membrane_thickness,
        membrane_modulus=specimen.membrane_modulus,
        particle_diameter=specimen.particle_diameter,
        specimen_diameter=specimen.specimen_diameter,
    )
    model = corrections.model
    # Where the record's own strain-ratio change is undefined (NaN), so is the fitted correction.
    undefined = ~np.all([np.isfinite(inputs[name]) for name in model.inputs], axis=0)
    rms = np.asarray(_prediction_rms(corrections), dtype=np.float64)
    # The abstention rule, per record: where it scales a stress's correction down, that stress's prediction
    # error is the region's error of the chosen factor on unseen cases (calibrate.abstention).
    shrink_axial, shrink_radial, region = abstention.record_shrink(
        corrections.abstention, inputs["stiffness_ratio"]
    )
    shrink = np.array([shrink_axial, shrink_radial])
    if region is not None:
        chosen = np.array([region[target]["rms"] for target in abstention.TARGETS])
        rms = np.where(shrink < 1.0, chosen, rms)
    # Thread-local float64 for the corrections (the process's setting is left alone); one compiled call.
    with jax.enable_x64(True), jax.numpy_dtype_promotion("standard"):
        arrays = _corrections_fn(model.name, tuple(corrections.names))(
            jnp.asarray([corrections.params[name] for name in corrections.names]),
            jnp.asarray(corrections.covariance),
            {name: jnp.asarray(np.nan_to_num(inputs[name])) for name in model.inputs},
            jnp.asarray(record.axial_strain),
            jnp.asarray(record.volumetric_strain),
            jnp.asarray(measured),
            jnp.asarray(cell),
            jnp.asarray([specimen.membrane_modulus, specimen.membrane_thickness, specimen.specimen_diameter]),
            jnp.asarray(rms),
            jnp.asarray(shrink),
        )
    arrays = jax.tree_util.tree_map(lambda a: np.asarray(a, dtype=np.float64), arrays)
    sigma_1, sigma_3, friction, std = arrays
    # Outside the fitted range the band widens by 1 + δ; beyond MAX_EXTRAPOLATION the method is withheld.
    # H/D_s, which no model reads, widens the band but does not withhold (module docstring).
    checked = dict(inputs)
    if specimen.height is not None:
        checked[ASPECT_RATIO] = np.full(cell.shape, specimen.height / specimen.specimen_diameter)
    distances = extrapolation_distances(checked, corrections.input_ranges)
    # The void ratio, outside the fitted members' span, widens and withholds like the model's inputs: the
    # extra stresses depend on how deep the membrane sinks into the voids.
    void_distance = void_ratio_distance(specimen, corrections.packing_family)
    zero = np.zeros(cell.shape)
    extrapolation = np.max([zero + void_distance, *distances.values()], axis=0)
    model_extrapolation = np.max(
        [zero + void_distance, *(d for n, d in distances.items() if n != ASPECT_RATIO)], axis=0
    )
    withheld = undefined | (model_extrapolation > MAX_EXTRAPOLATION)
    for values in (sigma_1, sigma_3, friction):
        values["fitted"] = np.where(withheld, np.nan, values["fitted"])
    std = {name: np.where(withheld, np.nan, value * (1.0 + extrapolation)) for name, value in std.items()}
    messages = range_warnings(checked, corrections.input_ranges, distances)
    messages += family_warnings(specimen, corrections.packing_family)
    if np.any(extrapolation > 0.0):
        messages.append(extrapolation_summary(extrapolation, undefined, model_extrapolation))
    messages += aspect_ratio_warnings(specimen, corrections.input_ranges)
    if region is not None and np.any(shrink < 1.0) and not np.all(withheld):
        value = float(np.median(inputs["stiffness_ratio"][np.isfinite(inputs["stiffness_ratio"])]))
        messages.append(abstention_warning(value, region, (shrink_axial, shrink_radial)))
    for message in messages:
        warnings.warn(message, stacklevel=2)
    alternate = None
    if corrections.alternate is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the same inputs: the chosen correction's warnings cover it
            alternate = correct_record(record, specimen, corrections.alternate)
    return CorrectedRecord(
        record,
        sigma_1,
        sigma_3,
        friction,
        std,
        inputs,
        tuple(messages),
        extrapolation,
        (shrink_axial, shrink_radial),
        corrections.radial_target,
        alternate,
    )


def extrapolation_summary(extrapolation, undefined, model_extrapolation=None) -> str:
    """The rule applied outside the fitted range, and what it did to this record (module docstring).

    Args:
      extrapolation: δ per row over every checked quantity (it widens the band).
      undefined: rows where the fitted correction is undefined.
      model_extrapolation: δ per row over the quantities that withhold the fitted correction (all but
        H/D_s); default ``extrapolation``.
    """
    model_extrapolation = extrapolation if model_extrapolation is None else model_extrapolation
    largest = float(np.max(extrapolation))
    beyond = int(np.sum((model_extrapolation > MAX_EXTRAPOLATION) & ~undefined))
    text = (
        "outside its fitted range the fitted correction's band is widened by the factor 1 + δ, δ being the "
        "largest distance outside the range in units of its width"
    )
    if beyond:
        return (
            f"{text}; beyond δ = {MAX_EXTRAPOLATION:g} the fitted correction is withheld: {beyond} of "
            f"{extrapolation.size} rows here (δ up to {largest:.2g}). The classical corrections are still "
            "given; a correction fitted on sweeps that cover this test (membrax sweep, then membrax fit) "
            "removes the warning."
        )
    return (
        f"{text}: up to ×{1.0 + largest:.2f} here (withheld beyond δ = {MAX_EXTRAPOLATION:g}, except for "
        "H/D_s, which no model reads: it only widens the band)."
    )
