"""membrax.config: defaults against the paper, exact SI conversions, TOML round trips and every refusal.

Units: the fields are in laboratory units named in their names (kPa, mm, degrees, kg/m³, N/m); the
properties are SI (Pa, m). Every bad input must raise ConfigError naming the field and its range or the
suggested key; files live in pytest's tmp_path.
"""

import dataclasses
import math

import pytest

from membrax import assemble
from membrax.config import (
    ConfigError,
    TriaxialConfig,
    config_from_dict,
    config_to_dict,
    dump_config_toml,
    inflation_ratio,
    load_config,
    parse_overrides,
    with_overrides,
)


def _write(tmp_path, text, name="run.toml"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# --- defaults and SI conversions -------------------------------------------------------------------------


#: The defaults that are the paper's values (laboratory units), and the run's name, output and safety factor.
PAPER_DEFAULTS = {
    "cell_pressure_kpa": 10.0,
    "membrane_thickness_mm": 5.0,
    "membrane_modulus_kpa": 1400.0,
    "particle_diameter_mm": 25.0,
    "friction_angle_deg": 25.0,
    "particles_across": 10,
    "layers": 25,
    "name": "membrax",
    "vtk_every_steps": 0,
    "dt_safety": 0.5,
}


def test_defaults_are_the_papers_values():
    cfg = TriaxialConfig()
    assert {field: getattr(cfg, field) for field in PAPER_DEFAULTS} == PAPER_DEFAULTS
    assert cfg.float64 is False


def test_si_conversions_are_exact():
    cfg = TriaxialConfig()
    assert cfg.cell_pressure == 1.0e4
    assert cfg.membrane_thickness == 0.005
    assert cfg.particle_diameter == 0.025
    assert cfg.particle_radius == 0.0125
    assert cfg.membrane_modulus == 1.4e6
    assert cfg.membrane_edge_length == 0.005
    assert cfg.friction_coefficient == math.tan(math.radians(25.0))
    assert cfg.membrane_friction_coefficient == math.tan(math.radians(25.0))
    assert cfg.friction_coefficient == pytest.approx(0.46630765815, rel=1e-10)
    other = TriaxialConfig(cell_pressure_kpa=40, membrane_thickness_mm=2.5, membrane_friction_angle_deg=0)
    assert other.cell_pressure == 4.0e4
    assert other.membrane_thickness == 0.0025
    assert other.membrane_friction_coefficient == 0.0


def test_consolidation_tolerance_zero_means_default():
    assert TriaxialConfig().consolidation_tolerance_or_none is None
    assert TriaxialConfig(consolidation_tolerance=2e-3).consolidation_tolerance_or_none == 2e-3


def test_frozen_and_types_are_normalised():
    cfg = TriaxialConfig(cell_pressure_kpa=40, layers=12.0)
    assert type(cfg.cell_pressure_kpa) is float and cfg.cell_pressure_kpa == 40.0
    assert type(cfg.layers) is int and cfg.layers == 12
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.layers = 3
    assert cfg.validate() is cfg


def test_docstring_lists_every_field_with_its_range():
    doc = TriaxialConfig.__doc__
    for field in dataclasses.fields(TriaxialConfig):
        assert f"{field.name} (" in doc, field.name
    for unit_phrase in ("kPa, in (0, inf)", "mm, in (0, inf)", "degrees, in [0, 90)", "kg/m³", "N/m"):
        assert unit_phrase in doc


# --- TOML round trips --------------------------------------------------------------------------------------


def test_toml_round_trip_defaults(tmp_path):
    cfg = TriaxialConfig()
    assert load_config(_write(tmp_path, dump_config_toml(cfg))) == cfg


#: The every-field round trip's values that test the TOML writer's edge cases (quotes, a non-ASCII letter and
#: a comment sign in a string; a float with no short decimal form; exponents; a table of pairs), and a choice
#: other than the default for each field that has choices; every other field takes :func:`_changed`.
EDGE_CASES = dict(
    name='run "A" ü #1 = x',
    membrane_thickness_mm=10.0 / 3.0,
    membrane_friction_angle_deg=1e-9,
    consolidation_tolerance=1e-17,
    grading=((9.5, 0.0), (12.5, 37.5), (19.0, 100.0)),
    membrane_law="gent",
    membrane_contact_model="faces",
    packing="random",
    damping_frame="absolute",
    cell="periodic",
)


def _changed(default):
    """A valid value other than ``default``: the other boolean, one more, or the float × 2/3 (0 gives 1e-3).

    Two thirds keeps every bounded float within its range and has no short decimal form, so the floats
    test the writer's shortest repr.
    """
    if isinstance(default, bool):
        return not default
    if isinstance(default, int):
        return default + 1
    return default * 2.0 / 3.0 if default else 1e-3


@pytest.mark.parametrize("table", [False, True])
def test_toml_round_trip_every_field_changed(tmp_path, table):
    defaults = TriaxialConfig()
    changed = {}
    for field in dataclasses.fields(TriaxialConfig):
        default = getattr(defaults, field.name)
        changed[field.name] = EDGE_CASES[field.name] if field.name in EDGE_CASES else _changed(default)
    cfg = TriaxialConfig(**changed)
    assert all(getattr(cfg, name) != getattr(defaults, name) for name in changed)
    text = dump_config_toml(cfg, table=table)
    assert text.count("[triaxial]") == int(table)
    loaded = load_config(_write(tmp_path, text))
    assert loaded == cfg
    assert config_to_dict(loaded) == config_to_dict(cfg)
    assert loaded.membrane_thickness_mm == 10.0 / 3.0  # bit-exact float


def test_partial_file_keeps_defaults_and_table_form(tmp_path):
    flat = load_config(_write(tmp_path, "cell_pressure_kpa = 40\nlayers = 12\n", "flat.toml"))
    table = load_config(_write(tmp_path, "[triaxial]\ncell_pressure_kpa = 40\nlayers = 12\n", "t.toml"))
    assert flat == table == TriaxialConfig(cell_pressure_kpa=40.0, layers=12)
    assert flat.membrane_thickness_mm == 5.0


def test_config_to_dict_and_from_dict():
    cfg = TriaxialConfig(layers=7)
    mapping = config_to_dict(cfg)
    assert list(mapping)[:2] == ["name", "particle_diameter_mm"]
    assert len(mapping) == len(dataclasses.fields(TriaxialConfig)) == 45
    assert config_from_dict(mapping) == cfg
    assert config_from_dict({}) == TriaxialConfig()


def test_with_overrides_and_parse_overrides():
    base = TriaxialConfig(layers=8)
    cfg = with_overrides(base, cell_pressure_kpa=100.0)
    assert (cfg.layers, cfg.cell_pressure_kpa) == (8, 100.0)
    assert base.cell_pressure_kpa == 10.0
    overrides = parse_overrides(["cell_pressure_kpa=40", "name = run1", "float64=true", 'name="a b"'])
    assert overrides == {"cell_pressure_kpa": 40, "name": "a b", "float64": True}
    assert config_from_dict(overrides, base=base) == TriaxialConfig(
        layers=8, cell_pressure_kpa=40.0, name="a b", float64=True
    )
    with pytest.raises(ConfigError, match=r"cell_pressure_kpa must be a number.*the string 'abc'"):
        config_from_dict(parse_overrides(["cell_pressure_kpa=abc"]))
    with pytest.raises(ConfigError, match="not of the form key=value"):
        parse_overrides(["cell_pressure_kpa"])
    with pytest.raises(ConfigError, match="did you mean `cell_pressure_kpa` \\(kPa\\)"):
        with_overrides(base, cell_pressure_pa=1e4)


# --- refusals ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("field", "value", "expected"),
    [
        (
            "cell_pressure_kpa",
            -10.0,
            "cell_pressure_kpa = -10 is outside the accepted range (0, inf). Unit: kPa",
        ),
        ("cell_pressure_kpa", 0.0, "cell_pressure_kpa = 0 is outside the accepted range (0, inf)"),
        (
            "membrane_thickness_mm",
            math.nan,
            "membrane_thickness_mm is NaN; accepted range is (0, inf). Unit: mm",
        ),
        (
            "particle_diameter_mm",
            math.inf,
            "particle_diameter_mm = inf is outside the accepted range (0, inf)",
        ),
        (
            "membrane_modulus_kpa",
            -math.inf,
            "membrane_modulus_kpa = -inf is outside the accepted range (0, inf)",
        ),
        (
            "friction_angle_deg",
            90.0,
            "friction_angle_deg = 90 is outside the accepted range [0, 90). Unit: degrees",
        ),
        (
            "membrane_friction_angle_deg",
            -1.0,
            "membrane_friction_angle_deg = -1 is outside the accepted range [0, 90)",
        ),
        ("target_axial_strain", 1.0, "target_axial_strain = 1 is outside the accepted range (0, 1)"),
        ("inertial_number", 0.2, "inertial_number = 0.2 is outside the accepted range (0, 0.1]"),
        ("dt_safety", 0.0, "dt_safety = 0 is outside the accepted range (0, 1]"),
        ("fine_until_strain", 1.0, "fine_until_strain = 1 is outside the accepted range [0, 1)"),
        (
            "consolidation_tolerance",
            -1e-3,
            "consolidation_tolerance = -0.001 is outside the accepted range [0, inf)",
        ),
        (
            "particle_density_kg_m3",
            0.0,
            "particle_density_kg_m3 = 0 is outside the accepted range (0, inf). Unit: kg/m³",
        ),
        (
            "particle_stiffness_n_m",
            -1.0,
            "particle_stiffness_n_m = -1 is outside the accepted range (0, inf). Unit: N/m",
        ),
        (
            "membrane_edges_per_diameter",
            0.0,
            "membrane_edges_per_diameter = 0 is outside the accepted range (0, inf)",
        ),
        ("particles_across", 1, "particles_across = 1 is outside the accepted range [2, inf)"),
        ("layers", 0, "layers = 0 is outside the accepted range [2, inf)"),
        ("consolidation_max_steps", 0, "consolidation_max_steps = 0 is outside the accepted range [1, inf)"),
        ("record_every_fine", 0, "record_every_fine = 0 is outside the accepted range [1, inf)"),
        ("record_every_coarse", -5, "record_every_coarse = -5 is outside the accepted range [1, inf)"),
        ("chunk_steps", 0, "chunk_steps = 0 is outside the accepted range [1, inf)"),
        ("checkpoint_every_chunks", 0, "checkpoint_every_chunks = 0 is outside the accepted range [1, inf)"),
        ("vtk_every_steps", -1, "vtk_every_steps = -1 is outside the accepted range [0, inf)"),
    ],
)
def test_out_of_range_names_field_range_value_and_unit(field, value, expected):
    with pytest.raises(ConfigError) as info:
        config_from_dict({field: value})
    assert expected in str(info.value)
    assert info.value.errors == (str(info.value),)
    with pytest.raises(ConfigError):  # the dataclass itself refuses it too
        TriaxialConfig(**{field: value})


def test_out_of_range_in_file_names_the_file(tmp_path):
    path = _write(tmp_path, "cell_pressure_kpa = -5.0\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}: cell_pressure_kpa = -5 is outside the accepted range (0, inf)")
    assert "kPa" in message
    assert info.value.source == str(path)


@pytest.mark.parametrize(
    ("key", "suggestion"),
    [
        ("cell_pressure_pa", "cell_pressure_kpa` (kPa)"),
        ("cell_pressure", "cell_pressure_kpa` (kPa)"),
        ("cell_pressure_MPa", "cell_pressure_kpa` (kPa)"),
        ("membrane_thickness_m", "membrane_thickness_mm` (mm)"),
        ("particle_diameter_cm", "particle_diameter_mm` (mm)"),
        ("membrane_modulus_mpa", "membrane_modulus_kpa` (kPa)"),
        ("friction_angle_rad", "friction_angle_deg` (degrees)"),
        ("membrane_friction_angle", "membrane_friction_angle_deg` (degrees)"),
        ("particle_density_g_cm3", "particle_density_kg_m3` (kg/m³)"),
        ("particle_stiffness_kn_m", "particle_stiffness_n_m` (N/m)"),
    ],
)
def test_wrong_unit_suffix_suggests_the_field(tmp_path, key, suggestion):
    path = _write(tmp_path, f"{key} = 1.0\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert f"unknown key `{key}`: did you mean `{suggestion}?" in str(info.value)


def test_unknown_keys(tmp_path):
    with pytest.raises(ConfigError, match="unknown key `layer`: did you mean `layers`\\?"):
        load_config(_write(tmp_path, "layer = 25\n"))
    with pytest.raises(ConfigError) as info:
        load_config(_write(tmp_path, "colour = 'red'\n"))
    assert "unknown key `colour`; the known keys are: name, particle_diameter_mm," in str(info.value)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        (
            'cell_pressure_kpa = "10"',
            "cell_pressure_kpa must be a number in (0, inf) kPa; got the string '10'",
        ),
        (
            "cell_pressure_kpa = true",
            "cell_pressure_kpa must be a number in (0, inf) kPa; got the boolean true",
        ),
        ("cell_pressure_kpa = [10]", "cell_pressure_kpa must be a number in (0, inf) kPa; got an array"),
        ("layers = 25.5", "layers must be an integer in [2, inf) layers; got 25.5. Give a whole number"),
        ("layers = nan", "layers must be an integer in [2, inf) layers; got nan"),
        ("float64 = 1", "float64 must be a boolean (true or false); got 1"),
        ('float64 = "true"', "float64 must be a boolean (true or false); got the string 'true'"),
        ("name = 3", "name must be a non-empty string; got 3"),
        ('name = ""', "name = '' is not usable in file names"),
        ('name = "a/b"', "name = 'a/b' is not usable in file names"),
        ("[cell_pressure_kpa]\nx = 1", "cell_pressure_kpa must be a number in (0, inf) kPa; got a table"),
    ],
)
def test_wrong_type(tmp_path, line, expected):
    with pytest.raises(ConfigError) as info:
        load_config(_write(tmp_path, line + "\n"))
    assert expected in str(info.value)


def test_integral_float_accepted_for_int_field(tmp_path):
    cfg = load_config(_write(tmp_path, "layers = 12.0\nconsolidation_max_steps = 2e5\n"))
    assert (cfg.layers, cfg.consolidation_max_steps) == (12, 200000)
    assert type(cfg.consolidation_max_steps) is int


def test_toml_nan_and_inf(tmp_path):
    with pytest.raises(ConfigError, match="cell_pressure_kpa is NaN; accepted range is \\(0, inf\\)"):
        load_config(_write(tmp_path, "cell_pressure_kpa = nan\n"))
    with pytest.raises(ConfigError, match="membrane_thickness_mm = inf is outside the accepted range"):
        load_config(_write(tmp_path, "membrane_thickness_mm = inf\n"))


def test_several_bad_fields_all_reported(tmp_path):
    text = 'cell_pressure_kpa = -1.0\nlayers = 1\nmembrane_thickness_m = 0.005\nfloat64 = "no"\n'
    with pytest.raises(ConfigError) as info:
        load_config(_write(tmp_path, text))
    error = info.value
    assert len(error.errors) == 4
    message = str(error)
    assert message.startswith("4 problems in the triaxial configuration in ")
    for part in (
        "did you mean `membrane_thickness_mm` (mm)?",
        "layers = 1 is outside the accepted range [2, inf)",
        "cell_pressure_kpa = -1 is outside the accepted range (0, inf)",
        "float64 must be a boolean",
    ):
        assert part in message
    with pytest.raises(ConfigError) as info:
        TriaxialConfig(cell_pressure_kpa=-1.0, layers=-2)
    assert len(info.value.errors) == 2


def test_malformed_toml_names_file_and_tomllib_message(tmp_path):
    path = _write(tmp_path, "cell_pressure_kpa = \nlayers 25\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert f"malformed TOML in {str(path)!r}" in message
    assert "(at line 1, column" in message  # tomllib's own position


def test_duplicate_key_is_malformed(tmp_path):
    with pytest.raises(ConfigError, match="malformed TOML"):
        load_config(_write(tmp_path, "layers = 3\nlayers = 4\n"))


def test_missing_file(tmp_path):
    path = tmp_path / "absent.toml"
    with pytest.raises(ConfigError, match=f"configuration file {str(path)!r} does not exist"):
        load_config(path)


def test_triaxial_table_must_hold_everything(tmp_path):
    with pytest.raises(ConfigError) as info:
        load_config(_write(tmp_path, "layers = 3\n[triaxial]\ncell_pressure_kpa = 40.0\n"))
    assert "keys `layers` sit outside the [triaxial] table" in str(info.value)
    with pytest.raises(ConfigError, match="`triaxial` must be a table"):
        load_config(_write(tmp_path, "triaxial = 3\n"))
    with pytest.raises(ConfigError, match="unknown key `cell_pressure_pa`: did you mean `cell_pressure_kpa`"):
        load_config(_write(tmp_path, "[triaxial]\ncell_pressure_pa = 1e4\n"))
    with pytest.raises(ConfigError, match="unknown key `other`"):
        load_config(_write(tmp_path, "[other]\nx = 1\n"))


def test_one_consolidation_tolerance_rule_for_every_stage():
    """One table: rigid 1e-3 / 5e-3, membrane 2e-3 / 2e-2 and periodic 1e-3 / 5e-3 (float64 / float32), the
    float32 values above the round-off floors the table's comment cites (~2e-3 rigid; 1.1e-2 with the
    membrane at 10 kPa; 1.6e-3 periodic); runs take their cell's for their precision unless the
    configuration gives one."""
    from membrax.defaults import default_consolidation_tolerance
    from membrax.run import consolidation_tolerance

    assert default_consolidation_tolerance("rigid", True) == 1e-3
    assert default_consolidation_tolerance("rigid", False) == 5e-3 > 2e-3
    assert default_consolidation_tolerance("membrane", True) == 2e-3
    assert default_consolidation_tolerance("membrane", False) == 2e-2 > 1.1e-2
    for float64 in (True, False):
        config = TriaxialConfig(float64=float64)
        assert consolidation_tolerance(config) == default_consolidation_tolerance("membrane", float64)
    assert consolidation_tolerance(TriaxialConfig(consolidation_tolerance=1e-4)) == 1e-4
    # The periodic element: float32's floor measured at 1.2e-3 to 1.6e-3 (defaults.py), under 5e-3.
    assert default_consolidation_tolerance("periodic", True) == 1e-3
    assert default_consolidation_tolerance("periodic", False) == 5e-3 > 1.6e-3
    periodic = TriaxialConfig(packing="random", cell="periodic")
    assert consolidation_tolerance(periodic) == default_consolidation_tolerance("periodic", False)
    with pytest.raises(ValueError, match="'rigid', 'membrane' or 'periodic'"):
        default_consolidation_tolerance("membran", True)


# --- random specimens --------------------------------------------------------------------------------------


def test_grading_is_converted_once_to_si_fractions():
    """[[20, 0], [25, 40], [31.5, 100]] (mm, %) is sieves of 0.02, 0.025, 0.0315 m passing 0, 0.4, 1."""
    cfg = TriaxialConfig(packing="random", grading=[[20, 0], [25, 40], [31.5, 100]])
    assert cfg.grading == ((20.0, 0.0), (25.0, 40.0), (31.5, 100.0))
    assert cfg.particle_grading.sizes == pytest.approx((0.02, 0.025, 0.0315), rel=1e-15)
    assert cfg.particle_grading.passing == pytest.approx((0.0, 0.4, 1.0), rel=1e-15)
    assert TriaxialConfig().particle_grading.largest == pytest.approx(0.025)  # equal spheres by default
    assert TriaxialConfig(compaction_friction_deg=45.0).compaction_friction_coefficient == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("fields", "expected"),
    [
        ({"packing": "rand"}, "packing must be one of 'fcc', 'random'; got the string 'rand'"),
        ({"grading": [[20, 0], [19, 100]]}, "point 2 has size 19 mm after 20 mm; sizes must increase"),
        ({"grading": [[20, 0], [25, 90]]}, "the last point passes 90 %; the curve must rise to 100 %"),
        ({"grading": [[20, 10], [25, 100]]}, "the first point passes 10 %; start the curve at 0 %"),
        ({"grading": [[20, 0], [25]]}, "point 2 is an array, not a [size mm, percent] pair"),
        ({"grading": "20 mm"}, "grading must be an array of [size mm, percent passing] pairs"),
        (
            {"packing": "random", "specimen_diameter_mm": 80.0},
            "specimen_diameter_mm = 80 mm holds fewer than 4 of the largest particles (25 mm)",
        ),
        (
            {"packing": "random", "grading": [[20, 0], [50, 100]], "specimen_height_mm": 150.0},
            "specimen_height_mm = 150 mm holds fewer than 4 of the largest particles (50 mm)",
        ),
    ],
)
def test_random_specimen_fields_are_refused_with_the_point_and_the_fix(fields, expected):
    with pytest.raises(ConfigError) as error:
        TriaxialConfig(**fields)
    assert expected in str(error.value)


def test_a_membrane_beyond_its_inflation_limit_is_refused_with_the_limit_and_the_fix():
    # Hand calculation: over the square window of 25 mm spheres, a = (√2 − 1) 12.5 = 5.178 mm, 1 mm of
    # 700 kPa holds 1.8353 (700/3)(1)/5.178 = 82.7 kPa (membrax.theory.membrane_limit_pressure).
    with pytest.raises(ConfigError) as error:
        TriaxialConfig(cell_pressure_kpa=100.0, membrane_thickness_mm=1.0, membrane_modulus_kpa=700.0)
    message = str(error.value)
    for named in (
        "cell_pressure_kpa = 100",
        "membrane_thickness_mm = 1",
        "membrane_modulus_kpa = 700",
        "82.7 kPa",
    ):
        assert named in message
    assert "846 kPa·mm" in message  # E_m t_m × 100/82.7, the least that holds 100 kPa
    # 1 mm of 1400 kPa holds 165 kPa: 0.60 of it, where runs went non-finite in shearing, is warned; 1 mm of
    # 2800 kPa (0.30 of its limit, the lab grid's e6_thin members, all completed) is quiet: the warning starts
    # at the largest ratio at which every lab-grid run completed.
    config = TriaxialConfig(cell_pressure_kpa=100.0, membrane_thickness_mm=1.0, membrane_modulus_kpa=1400.0)
    assert inflation_ratio(config_to_dict(config)) == pytest.approx(100.0 / 165.42, rel=1e-4)
    assert "0.60 of the membrane's inflation limit" in assemble.inflation_warning(config)
    stiffer = TriaxialConfig(cell_pressure_kpa=100.0, membrane_thickness_mm=1.0, membrane_modulus_kpa=2800.0)
    assert inflation_ratio(config_to_dict(stiffer)) == pytest.approx(100.0 / 330.84, rel=1e-4)
    assert assemble.inflation_warning(stiffer) is None
    # 60 kPa on 1 mm of 700 kPa: 0.725 of the limit, built with a warning.
    near = TriaxialConfig(cell_pressure_kpa=60.0, membrane_thickness_mm=1.0, membrane_modulus_kpa=700.0)
    assert "0.73 of the membrane's inflation limit" in assemble.inflation_warning(near)
    # A grading's windows are partly filled by its smaller particles: warned on its largest size, not refused.
    graded = TriaxialConfig(
        packing="random",
        grading=[[10.0, 0.0], [25.0, 100.0]],
        specimen_diameter_mm=150.0,
        specimen_height_mm=300.0,
        cell_pressure_kpa=100.0,
        membrane_thickness_mm=1.0,
        membrane_modulus_kpa=700.0,
    )
    assert inflation_ratio(config_to_dict(graded)) > 1.0


def test_the_inflation_refusal_follows_the_membrane_law():
    """1 mm of 700 kPa over 25 mm spheres at 84 kPa: past the neo-Hookean limit, 82.7 kPa (refused), below
    the Gent limit at J_m = 97.2, 1.8827 (700/3)(1)/5.178 = 84.8 kPa (accepted, warned at 0.99 of it); above
    it Gent refuses too, naming J_m; below J_m = 32.62 Gent has no limit point and SVK none at all (a ratio
    of 0). The unknown law and a non-finite or non-positive J_m are refused naming the field and its
    choices."""
    thin = dict(cell_pressure_kpa=84.0, membrane_thickness_mm=1.0, membrane_modulus_kpa=700.0)
    with pytest.raises(ConfigError, match=r"82\.7 kPa"):
        TriaxialConfig(**thin)
    gent = TriaxialConfig(**thin, membrane_law="gent")
    assert gent.stretching_model == "gent"
    assert inflation_ratio(config_to_dict(gent)) == pytest.approx(84.0 / 84.845, rel=1e-4)
    assert "0.99 of the membrane's inflation limit" in assemble.inflation_warning(gent)
    with pytest.raises(ConfigError) as error:
        TriaxialConfig(**{**thin, "cell_pressure_kpa": 100.0}, membrane_law="gent")
    for named in ("84.8 kPa", "Gent sheet's inflation limit at J_m = 97.2, 1.88 (E_m/3) t_m / a"):
        assert named in str(error.value)
    soft = dict(thin, cell_pressure_kpa=1000.0)
    assert (
        inflation_ratio(config_to_dict(TriaxialConfig(**soft, membrane_law="gent", membrane_locking_jm=30.0)))
        == 0
    )
    assert inflation_ratio(config_to_dict(TriaxialConfig(**soft, membrane_law="svk"))) == 0
    assert TriaxialConfig().stretching_model == "neo_hookean"
    with pytest.raises(ConfigError, match="membrane_law must be one of 'neo-hookean', 'gent', 'svk'"):
        TriaxialConfig(membrane_law="neo_hookean")
    for bad in (0.0, -3.0, math.inf, math.nan):
        with pytest.raises(ConfigError, match="membrane_locking_jm"):
            TriaxialConfig(membrane_law="gent", membrane_locking_jm=bad)


def test_the_ballast_grading_scales_parallel_and_its_d50_is_the_hand_value():
    from membrax.config import BALLAST_GRADING_MM, characteristic_size_mm, scaled_grading

    scaled = scaled_grading(BALLAST_GRADING_MM, 25.0)
    factor = 25.0 / 63.0
    for (size, percent), (full_size, full_percent) in zip(scaled, BALLAST_GRADING_MM, strict=True):
        assert size == pytest.approx(factor * full_size, rel=1e-12) and percent == full_percent
    # d50 at full size: 40 + (50 − 47.5)/(85 − 47.5) × 10 = 40.667 mm, by hand; scaled by 25/63
    d50 = characteristic_size_mm({"grading": scaled, "particle_diameter_mm": 99.0})
    assert d50 == pytest.approx(factor * (40.0 + 2.5 / 37.5 * 10.0), rel=1e-12)
    assert characteristic_size_mm({"grading": (), "particle_diameter_mm": 25.0}) == 25.0
    for bad in (0.0, -3.0, float("nan")):
        with pytest.raises(ValueError, match="largest_mm"):
            scaled_grading(BALLAST_GRADING_MM, bad)


def test_a_compaction_friction_names_its_packing_state():
    import math as m

    from membrax.config import compaction_state

    assert compaction_state(0.0) == "dense"
    assert compaction_state(m.degrees(m.atan(0.5))) == "loose"  # tan⁻¹ 0.5, as COMPACTION_FRICTION_DEG
    assert compaction_state(10.0) == "medium"
    assert compaction_state(15.0) == "compaction friction 15°"


def test_the_shipped_configuration_files_are_the_presets_they_name():
    """examples/configs/*.toml, which the README's commands use, load to the demo, random-demo, periodic-demo
    and paper configurations (the presets are the one source; the files must not drift from them)."""
    from pathlib import Path

    from membrax.config import (
        DEMO_CONFIG,
        DEMO_RANDOM_CONFIG,
        PERIODIC_DEMO_CONFIG,
        TriaxialConfig,
        load_config,
    )
    from membrax.reproduce import SIZES

    folder = Path(__file__).resolve().parents[1] / "examples" / "configs"
    expected = {
        "demo.toml": TriaxialConfig(**DEMO_CONFIG),
        "demo_random.toml": TriaxialConfig(**DEMO_RANDOM_CONFIG),
        "periodic.toml": TriaxialConfig(**{**DEMO_RANDOM_CONFIG, **PERIODIC_DEMO_CONFIG}),
        "paper.toml": TriaxialConfig(name="paper", **SIZES["paper"]),
    }
    assert sorted(p.name for p in folder.glob("*.toml")) == sorted(expected)
    for name, config in expected.items():
        assert load_config(folder / name) == config, name
    assert expected["paper.toml"].particles_across == 10 and expected["paper.toml"].layers == 25  # Table 1


def test_the_membrane_contact_model_is_one_of_the_two_and_a_typo_names_the_field():
    """membrane_contact_model: "nodes" (default) or "faces"; anything else is refused with the choices."""
    from membrax.defaults import MEMBRANE_CONTACT_MODELS

    assert TriaxialConfig().membrane_contact_model == "nodes" == MEMBRANE_CONTACT_MODELS[0]
    assert TriaxialConfig(membrane_contact_model="faces").membrane_contact_model == "faces"
    with pytest.raises(ValueError, match=r"membrane_contact_model must be one of 'nodes', 'faces'"):
        TriaxialConfig(membrane_contact_model="triangles")
