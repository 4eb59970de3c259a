"""Post-processing of a membrane triaxial test: external against internal stresses (the paper's §4.3, §5.2).

Contract. Every function takes ``records``, a mapping from a name to the 1-D series of one quantity over
the records of the shearing stage (a ``dict`` of numpy or JAX arrays, or an ``xarray.Dataset``; each is read
as ``np.asarray(records[name], dtype=float64)`` with a trailing size-1 axis squeezed). The names are:

- ``step``, ``time`` (s), ``axial_strain`` ε_a, ``volumetric_strain`` ε_v, ``radial_strain`` ε_r
  (fractions, compression positive, so a bulging specimen has ε_r < 0);
- ``external_axial_stress``: ram force over the platen area updated for right-cylinder deformation (Pa);
- ``external_radial_stress``: the cell pressure (Pa);
- ``internal_axial_stress``: force received by the particles from the platen (membrane forces carried
  through the platen included) over the same area (Pa);
- ``internal_radial_stress``: radial force received by the boundary particles from the membrane over the
  lateral area of the right cylinder (Pa);
- ``love_weber_axial_stress``, ``love_weber_radial_stress``: the volume-averaged particle stress (Pa),
  optional (used only when present).

Everything runs on the host in numpy float64 and nothing is traced. Results are numpy arrays or plain
floats; stresses are returned in Pa except where a name ends in ``_kpa``, strains as fractions, angles in
degrees. The mobilised friction angle is :func:`membrax.theory.mobilised_friction_angle_deg` (evaluated by
JAX, so in float32 unless ``JAX_ENABLE_X64=1``; about 1e-5° of rounding) and is NaN wherever σ1 or σ3 is
not a positive finite number. Nothing here warns on zero or NaN data: undefined values come back as NaN.

Definitions (the paper's §4.3 and §5.2; formulas in ``shared/reference/membrane-corrections.md`` §9):

- additional (membrane) stress Δσ = σ_internal − σ_external (Fig. 6);
- stress ratio σ_internal/σ_external (Figs 7 and 8);
- mobilised friction angle sin φ' = (σ1 − σ3)/(σ1 + σ3) with σ1 axial, σ3 radial (Fig. 5, Table 2);
- change in strain ratio dε_r/dε_a, a local regression slope (Fig. 7), see :func:`strain_ratio_change`.

:data:`membrax.paper.PAPER_10KPA_5MM` holds the paper's numbers for the 10 kPa, 5 mm membrane test that
Figs 5–8 show, with the keys of :func:`initial_state`, :func:`peak` and :func:`largest_overestimate`, for
:func:`summary_table`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from membrax.theory import mobilised_friction_angle_deg

__all__ = [
    "RECORD_NAMES",
    "record",
    "STRAIN_RATIO_WINDOW",
    "strain_ratio_change",
    "friction_angle_deg",
    "derived_quantities",
    "initial_state",
    "peak",
    "largest_overestimate",
    "summary_table",
    "LATE_STRAIN_FRACTION",
    "late_mean",
    "element_summary",
    "element_summary_table",
]

KPA_PER_PA = 1e-3

#: Names of the record series this module reads (``love_weber_*`` are optional).
RECORD_NAMES = (
    "step",
    "time",
    "axial_strain",
    "volumetric_strain",
    "radial_strain",
    "external_axial_stress",
    "external_radial_stress",
    "internal_axial_stress",
    "internal_radial_stress",
    "love_weber_axial_stress",
    "love_weber_radial_stress",
)


def record(records, name: str) -> np.ndarray:
    """One series of ``records`` as a 1-D float64 numpy array.

    Args:
      records: a mapping (``dict``, ``xarray.Dataset``) with ``records[name]`` array-like (numpy, JAX,
        ``xarray.DataArray``).
      name: the series' name, one of :data:`RECORD_NAMES`.

    Returns:
      ``np.asarray(records[name], dtype=float64)``, with a trailing size-1 axis squeezed.

    Raises:
      KeyError: if ``name`` is missing.
      ValueError: if the series is not 1-D after squeezing.
    """
    if name not in records:
        raise KeyError(f"records has no series {name!r}; expected the names {RECORD_NAMES}.")
    values = np.asarray(records[name], dtype=np.float64)
    if values.ndim > 1 and values.shape[-1] == 1:
        values = values[..., 0]
    if values.ndim != 1:
        raise ValueError(f"records[{name!r}] has shape {values.shape}; expected one value per record (1-D).")
    return values


def _ratio(numerator: np.ndarray, denominator: np.ndarray) -> np.ndarray:
    """numerator/denominator, NaN where the denominator is zero or either value is not finite."""
    out = np.full(np.broadcast(numerator, denominator).shape, np.nan)
    defined = np.isfinite(numerator) & np.isfinite(denominator) & (denominator != 0.0)
    np.divide(numerator, denominator, out=out, where=defined)
    return out


def friction_angle_deg(major: np.ndarray, minor: np.ndarray) -> np.ndarray:
    """Mobilised φ' (degrees) from :func:`membrax.theory.mobilised_friction_angle_deg`, NaN where undefined.

    sin φ' = (σ1 − σ3)/(σ1 + σ3)   [C, standard; reference §9]. Records where σ1 or σ3 is not a positive
    finite number get NaN (theory would raise on them), the others are passed to theory as they are.
    """
    major = np.asarray(major, dtype=np.float64)
    minor = np.asarray(minor, dtype=np.float64)
    defined = np.isfinite(major) & np.isfinite(minor) & (major > 0.0) & (minor > 0.0)
    angle = np.full(np.broadcast(major, minor).shape, np.nan)
    if defined.any():
        angle[defined] = np.asarray(mobilised_friction_angle_deg(major[defined], minor[defined]))
    return angle


#: The strain window (0.5 % axial strain) of :func:`strain_ratio_change` in every record membrax writes.
STRAIN_RATIO_WINDOW = 0.005


def strain_ratio_change(axial_strain, radial_strain, window: float = STRAIN_RATIO_WINDOW) -> np.ndarray:
    """The change in strain ratio dε_r/dε_a (the paper's Fig. 7), as a moving local linear regression.

    For each record i the slope of the least-squares line of ε_r against ε_a through the records j whose
    axial strain lies within the window, |ε_a,j − ε_a,i| <= ``window``/2 (record i included):

        dε_r/dε_a |_i = Σ_j (ε_a,j − ē_a)(ε_r,j − ē_r) / Σ_j (ε_a,j − ē_a)²

    where ē_a, ē_r are the means over the window. This is a Savitzky–Golay filter of order 1 (the
    derivative of a local linear least-squares fit; Savitzky & Golay 1964, Anal. Chem. 36(8), 1627–1639)
    with a window fixed in strain instead of in number of records, so it works on non-uniformly spaced
    records (the recording is dense below 1 % strain and coarser after) and smooths the same strain range
    everywhere. The paper defines the quantity as "the change in radial strain/change in axial strain"
    (§5.2) without stating its smoothing; a plain finite difference of noisy DEM strains is too rough to
    compare with the stress ratio, hence the regression.

    Accuracy. For ε_r = a ε_a + b ε_a² the slope is a + 2b ē_a + b m3/m2, where m2 and m3 are the second
    and third central moments of ε_a in the window: it is the exact derivative at the record itself when
    the records in its window are placed symmetrically about it (uniform spacing away from the ends), and
    at the window's centroid up to the skewness term otherwise. A window of 0.5 % strain keeps the second
    peak of the paper's test (about 6 %) resolved while averaging over a few hundred dense records at the
    start of shearing.

    Args:
      axial_strain: ε_a per record, fractions, compression positive; any order (need not be monotonic).
      radial_strain: ε_r per record, same length.
      window: full width of the strain window (fraction; 0.005 = 0.5 % strain), > 0.

    Returns:
      float64 array of dε_r/dε_a per record; NaN where the window holds fewer than 3 records with finite
      strains, where all its axial strains are equal, or where the record's own strains are not finite.

    Raises:
      ValueError: if ``window`` is not a positive finite number or the lengths differ.
    """
    axial = np.asarray(axial_strain, dtype=np.float64).reshape(-1)
    radial = np.asarray(radial_strain, dtype=np.float64).reshape(-1)
    if axial.shape != radial.shape:
        raise ValueError(f"axial_strain has {axial.size} records and radial_strain {radial.size}.")
    window = float(window)
    if not (np.isfinite(window) and window > 0.0):
        raise ValueError(f"window = {window} must be a positive strain (0.005 for 0.5 %).")
    half = 0.5 * window
    slope = np.full(axial.shape, np.nan)
    usable = np.flatnonzero(np.isfinite(axial) & np.isfinite(radial))
    order = usable[np.argsort(axial[usable], kind="stable")]
    x_sorted = axial[order]
    y_sorted = radial[order]
    starts = np.searchsorted(x_sorted, x_sorted - half, side="left")
    stops = np.searchsorted(x_sorted, x_sorted + half, side="right")
    slope[order] = _window_slopes(x_sorted, y_sorted, starts, stops)
    return slope


def _window_slopes(x, y, starts, stops) -> np.ndarray:
    """Least-squares slopes of y on x over the windows [starts[k], stops[k]) of sorted x, in O(records).

    Both ends only move forward as k grows, so the window slides: each record enters and leaves once, and
    the window's means and central (co)moments are updated as it does (Welford's update and its inverse;
    Welford 1962, Technometrics 4(3), 419–420), which keeps deviations from the window's own mean and so
    avoids the cancellation of running sums of x² over a whole record. They are summed afresh, two-pass,
    whenever the window has been replaced entirely since the last fresh sum, which bounds the updates'
    round-off to one window's worth. NaN where a window holds fewer than 3 records or no spread in x.
    """
    count = len(x)
    slope = np.full(count, np.nan)
    xs, ys = x.tolist(), y.tolist()
    starts, stops = starts.tolist(), stops.tolist()
    low = high = fresh_until = 0  # the window [low, high); summed afresh up to fresh_until
    members, mean_x, mean_y, sxx, sxy = 0, 0.0, 0.0, 0.0, 0.0
    for k in range(count):
        start, stop = starts[k], stops[k]
        if start >= fresh_until:
            low, high = start, stop
            fresh_until = stop
            members = stop - start
            window_x, window_y = x[start:stop], y[start:stop]
            mean_x, mean_y = float(window_x.mean()), float(window_y.mean())
            dx = window_x - mean_x
            sxx, sxy = float(np.dot(dx, dx)), float(np.dot(dx, window_y - mean_y))
        else:
            while high < stop:  # enter: C_n = C_(n−1) + (x − x̄_(n−1))(y − ȳ_n)
                members += 1
                dx = xs[high] - mean_x
                mean_x += dx / members
                mean_y += (ys[high] - mean_y) / members
                sxx += dx * (xs[high] - mean_x)
                sxy += dx * (ys[high] - mean_y)
                high += 1
            while low < start:  # leave: the inverse, C_(n−1) = C_n − (x − x̄_(n−1))(y − ȳ_n)
                members -= 1  # at least stop − start >= 1 remain
                old_x, old_y = mean_x, mean_y
                mean_x -= (xs[low] - old_x) / members
                mean_y -= (ys[low] - old_y) / members
                dx = xs[low] - mean_x
                sxx -= dx * (xs[low] - old_x)
                sxy -= dx * (ys[low] - old_y)
                low += 1
        if members >= 3 and xs[start] != xs[stop - 1]:  # sorted, so no spread when the ends are equal
            slope[k] = sxy / sxx
    return slope


def derived_quantities(records, window: float = STRAIN_RATIO_WINDOW) -> dict[str, np.ndarray]:
    """The derived series of the paper's Figs 5–8, one value per record.

    Keys (Pa, fractions, degrees):

    - ``additional_axial_stress``: Δσ_a = σ_a,internal − σ_a,external (Fig. 6);
    - ``additional_radial_stress``: Δσ_r = σ_r,internal − σ_r,external (Fig. 6);
    - ``axial_stress_ratio``: σ_a,internal/σ_a,external (Fig. 7), NaN where the external stress is 0;
    - ``radial_stress_ratio``: σ_r,internal/σ_r,external (Fig. 8), NaN likewise;
    - ``external_friction_angle_deg``, ``internal_friction_angle_deg`` and, when the records have the
      Love–Weber series, ``love_weber_friction_angle_deg``: the mobilised φ' from
      sin φ' = (σ1 − σ3)/(σ1 + σ3), σ1 axial and σ3 radial   [C, standard; reference §9] (Fig. 5,
      Table 2), NaN where a stress is not positive;
    - ``strain_ratio_change``: dε_r/dε_a from :func:`strain_ratio_change` with ``window`` (Fig. 7).

    Args:
      records: the test records (see the module docstring).
      window: strain window of :func:`strain_ratio_change` (fraction).

    Returns:
      A dict of float64 arrays, each as long as the records.
    """
    external_axial = record(records, "external_axial_stress")
    external_radial = record(records, "external_radial_stress")
    internal_axial = record(records, "internal_axial_stress")
    internal_radial = record(records, "internal_radial_stress")
    derived = {
        "additional_axial_stress": internal_axial - external_axial,
        "additional_radial_stress": internal_radial - external_radial,
        "axial_stress_ratio": _ratio(internal_axial, external_axial),
        "radial_stress_ratio": _ratio(internal_radial, external_radial),
        "external_friction_angle_deg": friction_angle_deg(external_axial, external_radial),
        "internal_friction_angle_deg": friction_angle_deg(internal_axial, internal_radial),
    }
    if "love_weber_axial_stress" in records and "love_weber_radial_stress" in records:
        derived["love_weber_friction_angle_deg"] = friction_angle_deg(
            record(records, "love_weber_axial_stress"), record(records, "love_weber_radial_stress")
        )
    derived["strain_ratio_change"] = strain_ratio_change(
        record(records, "axial_strain"), record(records, "radial_strain"), window
    )
    return derived


def initial_state(records, index: int = 0) -> dict:
    """Initial external and internal principal stresses in kPa, as in the paper's Table 3.

    Args:
      records: the test records (see the module docstring); ``index`` 0 is the first shearing record when
        the records hold the shearing stage only.
      index: the record to read (negative counts from the end).

    Returns:
      ``{"index", "axial_strain", "sigma3_external_kpa", "sigma3_internal_kpa", "sigma1_external_kpa",
      "sigma1_internal_kpa"}`` with σ3 the radial and σ1 the axial stress converted from Pa to kPa,
      ``index`` made non-negative and ``axial_strain`` a fraction.
    """
    axial_strain = record(records, "axial_strain")
    index = range(axial_strain.size)[index]
    return {
        "index": index,
        "axial_strain": float(axial_strain[index]),
        "sigma3_external_kpa": float(record(records, "external_radial_stress")[index] * KPA_PER_PA),
        "sigma3_internal_kpa": float(record(records, "internal_radial_stress")[index] * KPA_PER_PA),
        "sigma1_external_kpa": float(record(records, "external_axial_stress")[index] * KPA_PER_PA),
        "sigma1_internal_kpa": float(record(records, "internal_axial_stress")[index] * KPA_PER_PA),
    }


def _nan_argmax(values: np.ndarray) -> int | None:
    """Index of the largest non-NaN value (the first one on ties), ``None`` when all are NaN."""
    finite = np.isfinite(values)
    if not finite.any():
        return None
    return int(np.argmax(np.where(finite, values, -np.inf)))


def peak(records, derived: Mapping | None = None) -> dict:
    """Peak external and internal mobilised friction angles and where they occur (the paper's Table 2).

    Args:
      records: the test records (see the module docstring).
      derived: the result of :func:`derived_quantities` for these records, computed when not given.

    Returns:
      ``{"peak_external_friction_angle_deg", "peak_external_axial_strain", "peak_external_index",
      "peak_internal_friction_angle_deg", "peak_internal_axial_strain", "peak_internal_index"}``: the
      largest φ' (degrees), the axial strain (fraction) and the record index of the first record reaching
      it. NaN angles and strains and a ``None`` index when no record has a defined φ'.
    """
    derived = derived_quantities(records) if derived is None else derived
    axial_strain = record(records, "axial_strain")
    result = {}
    for side in ("external", "internal"):
        angle = np.asarray(derived[f"{side}_friction_angle_deg"], dtype=np.float64)
        index = _nan_argmax(angle)
        result[f"peak_{side}_friction_angle_deg"] = np.nan if index is None else float(angle[index])
        result[f"peak_{side}_axial_strain"] = np.nan if index is None else float(axial_strain[index])
        result[f"peak_{side}_index"] = index
    return result


def largest_overestimate(records, min_strain: float = 0.0, derived: Mapping | None = None) -> dict:
    """Where the external φ' exceeds the internal φ' most (the paper's Fig. 5: "by up to 4°").

    Δφ' = φ'_external − φ'_internal (degrees), maximised over the records with ε_a >= ``min_strain``.

    Args:
      records: the test records (see the module docstring).
      min_strain: smallest axial strain considered (fraction; e.g. 0.03 for "beyond about 3 %").
      derived: the result of :func:`derived_quantities` for these records, computed when not given.

    Returns:
      ``{"overestimate_deg", "overestimate_axial_strain", "overestimate_index"}``: the largest Δφ'
      (negative when the external φ' is below the internal one everywhere), its axial strain (fraction) and
      record index; NaN and ``None`` when no record qualifies.
    """
    derived = derived_quantities(records) if derived is None else derived
    axial_strain = record(records, "axial_strain")
    difference = np.asarray(derived["external_friction_angle_deg"], dtype=np.float64) - np.asarray(
        derived["internal_friction_angle_deg"], dtype=np.float64
    )
    difference = np.where(axial_strain >= float(min_strain), difference, np.nan)
    index = _nan_argmax(difference)
    return {
        "overestimate_deg": np.nan if index is None else float(difference[index]),
        "overestimate_axial_strain": np.nan if index is None else float(axial_strain[index]),
        "overestimate_index": index,
    }


#: Rows of :func:`summary_table`: (key, label, scale to display unit, decimals).
_SUMMARY_ROWS = (
    ("sigma3_external_kpa", "Initial σ3 external (kPa) [Table 3]", 1.0, 2),
    ("sigma3_internal_kpa", "Initial σ3 internal (kPa) [Table 3]", 1.0, 2),
    ("sigma1_external_kpa", "Initial σ1 external (kPa) [Table 3]", 1.0, 2),
    ("sigma1_internal_kpa", "Initial σ1 internal (kPa) [Table 3]", 1.0, 2),
    ("peak_external_friction_angle_deg", "Peak φ' external (°) [Table 2]", 1.0, 2),
    ("peak_external_axial_strain", "Axial strain at peak φ' external (%) [§5.2]", 100.0, 2),
    ("peak_internal_friction_angle_deg", "Peak φ' internal (°) [Table 2]", 1.0, 2),
    ("peak_internal_axial_strain", "Axial strain at peak φ' internal (%) [§5.2]", 100.0, 2),
    ("overestimate_deg", "Largest φ' external − internal (°) [Fig. 5]", 1.0, 2),
    ("overestimate_axial_strain", "Axial strain of the largest difference (%) [Fig. 5]", 100.0, 2),
)


def _cell(value, scale: float, decimals: int) -> str:
    if value is None or not np.isfinite(value):
        return "–"
    return f"{float(value) * scale:.{decimals}f}"


def summary_table(records, paper: Mapping | None = None, *, min_strain: float = 0.0) -> str:
    """A Markdown table of :func:`initial_state`, :func:`peak` and :func:`largest_overestimate`.

    Args:
      records: the test records (see the module docstring).
      paper: optional values to show beside the run's, keyed like the results (e.g.
        :data:`membrax.paper.PAPER_10KPA_5MM`); a missing key shows "–".
      min_strain: passed to :func:`largest_overestimate`.

    Returns:
      The table as a string: one row per quantity (stresses in kPa, angles in degrees, strains in %), the
      columns "Quantity", "This run" and, with ``paper``, "Paper".
    """
    derived = derived_quantities(records)
    values = {
        **initial_state(records),
        **peak(records, derived),
        **largest_overestimate(records, min_strain, derived),
    }
    header = ["Quantity", "This run"] + (["Paper"] if paper is not None else [])
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|"]
    for key, label, scale, decimals in _SUMMARY_ROWS:
        cells = [label, _cell(values[key], scale, decimals)]
        if paper is not None:
            cells.append(_cell(paper.get(key), scale, decimals))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------------------
# The periodic element test (:mod:`membrax.triaxial.periodic`): one stress, the cell's Love–Weber stress
# ---------------------------------------------------------------------------------------------------------

#: "Late" (large-strain) values are means over the records at axial strains from this fraction of the last
#: one on (the last fifth of the strain range): one record's scatter does not set them.
LATE_STRAIN_FRACTION = 0.8


def late_mean(axial_strain, values, fraction: float = LATE_STRAIN_FRACTION) -> float:
    """The mean of ``values`` over the records with ε_a ≥ ``fraction`` × the last ε_a (NaN when none)."""
    axial_strain, values = np.asarray(axial_strain, dtype=float), np.asarray(values, dtype=float)
    late = axial_strain >= fraction * axial_strain[-1]
    return float(np.nanmean(values[late])) if np.any(late) else float("nan")


def element_summary(records, cell_pressure: float) -> dict:
    """The figures of a periodic element test's shearing records (σ1 axial, σ3 the lateral mean).

    Args:
      records: the shearing records with ``axial_strain``, ``volumetric_strain``, ``axial_stress``,
        ``lateral_stress`` (Pa), ``stress`` (R, 3, 3), ``solid_fraction``, ``coordination_number`` and
        ``rattler_free_coordination_number``; the first record the start of shearing.
      cell_pressure: σc, Pa (the lateral servo's target).

    Returns:
      ``peak_friction_angle_deg`` and its ``peak_axial_strain``, ``late_friction_angle_deg``
      (:func:`late_mean`), ``final_volumetric_strain`` (compression positive), ``lateral_stress_error``
      (the largest |σ_kk/σc − 1| of x and y over the records), and at the start of shearing
      ``solid_fraction``, ``coordination_number`` and ``rattler_free_coordination_number``.
    """
    strain = record(records, "axial_strain")
    angle = friction_angle_deg(record(records, "axial_stress"), record(records, "lateral_stress"))
    stress = np.asarray(records["stress"], dtype=float)
    lateral = np.stack([stress[:, 0, 0], stress[:, 1, 1]])
    index = _nan_argmax(angle)
    return {
        "peak_friction_angle_deg": float("nan") if index is None else float(angle[index]),
        "peak_axial_strain": float("nan") if index is None else float(strain[index]),
        "late_friction_angle_deg": late_mean(strain, angle),
        "final_volumetric_strain": float(record(records, "volumetric_strain")[-1]),
        "lateral_stress_error": float(np.max(np.abs(lateral / cell_pressure - 1.0))),
        "solid_fraction": float(record(records, "solid_fraction")[0]),
        "coordination_number": float(record(records, "coordination_number")[0]),
        "rattler_free_coordination_number": float(record(records, "rattler_free_coordination_number")[0]),
    }


def element_summary_table(records, cell_pressure: float) -> str:
    """:func:`element_summary` as a Markdown table (degrees, %, kPa)."""
    figures = element_summary(records, cell_pressure)
    rows = [
        ("Peak φ' (°)", f"{figures['peak_friction_angle_deg']:.2f}"),
        ("at ε_a (%)", f"{100 * figures['peak_axial_strain']:.2f}"),
        (
            f"Late φ' (°), mean over ε_a ≥ {LATE_STRAIN_FRACTION:g} × the last",
            f"{figures['late_friction_angle_deg']:.2f}",
        ),
        ("ε_v at the end (%, compression +)", f"{100 * figures['final_volumetric_strain']:.2f}"),
        ("Largest lateral stress error (% of σc)", f"{100 * figures['lateral_stress_error']:.2f}"),
        ("Solid fraction at the start of shearing", f"{figures['solid_fraction']:.4f}"),
        (
            "z, z* (rattlers removed) at the start",
            f"{figures['coordination_number']:.2f}, {figures['rattler_free_coordination_number']:.2f}",
        ),
        ("σc (kPa)", f"{KPA_PER_PA * cell_pressure:g}"),
    ]
    return (
        "| Quantity | membrax |\n|---|---|\n"
        + "\n".join(f"| {name} | {value} |" for name, value in rows)
        + "\n"
    )
