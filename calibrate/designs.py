"""The calibration designs: the membrax sweeps a correction is fitted on, and the held-out tests.

Contract. :data:`DESIGNS` names the designs (one source for each): :data:`LAB_CALIBRATION` (the shipped
correction's), :data:`LAB_HELD_OUT`, :data:`LAB_THIN`, :data:`RANDOM_CALIBRATION` (the previous
correction's), :data:`RANDOM_HELD_OUT`, :data:`PROTOCOL_CHECK`, :data:`CONTACT_CHECK`, and the FCC
:data:`CALIBRATION` and :data:`HELD_OUT` of the first correction. Each maps a group name to ``(specimen,
grid)``: the specimen's fields (:func:`specimen_fields`) and the ``membrax sweep`` grid of that specimen.
Running them is :mod:`calibrate.grid`'s.

Random specimens. A laboratory specimen is a random packing, and corrections do not transfer between packings
(docs/calibration.md), so the corrections are fitted on random packings. The random grid: equal 25 mm spheres
in moulds 150, 200 and 250 mm across (D/D_s = 1/6, 1/8, 1/10), dense and loose, and railway ballast's grading
scaled to a largest sieve of D_s/6 (:func:`membrax.reproduce.random_fields`), dense and loose; σc 10–100 kPa,
t_m 1–5 mm, E_m 700–2800 kPa; packing seed 0. The held-out members are packings of seed 1 off every grid line.
:data:`PROTOCOL_CHECK` reruns nine members at the paper's rate and membrane resolution.

Why small specimens. Every random-grid group uses the small preset of ``membrax reproduce``
(:data:`membrax.reproduce.SIZES` ``"small"``: a membrane of edge D/3, inertial number 5e-3, float64,
consolidation to an unbalanced-force ratio ≤ 1e-3): the extra stresses depend on the groups the models use
(t_m/D, E_m t_m/(σc D), D/D_s, the strains), which the grid spans, rather than on the specimen's height, and a
paper-size member costs about 2.5 min on 2 cores. FCC: 6, 8 and 10 spheres across give D/D_s = 1/5.7, 1/7.4
and 1/10 (D_s = √(4A/π) of the platen area), heights H/D_s ≈ 1.25; its held-out members (σc 25 and 70 kPa, t_m
2 and 4 mm, E_m 1000 and 2000 kPa) are 7 spheres across (D/D_s = 1/7).

At a laboratory's geometry. :data:`LAB_CALIBRATION` (``--design lab``) is the shipped correction's training
set: moulds of H/D 2 and 2.5, 150–300 mm, the paper's protocol, dense, medium and loose states, equal, ballast
and narrow gradings, two seeds per group (150 members); :data:`LAB_HELD_OUT` (``--design lab_held_out``, 18
members) its held-out members, off its σc and t_m grid lines and seeds. Run it as a campaign (``--scheduler
local``): it is resumable, group by group and member by member.

Run: :mod:`calibrate.grid` (``python -m calibrate.grid OUT --design NAME``).
"""

from __future__ import annotations

__all__ = [
    "CALIBRATION",
    "CONTACT_CHECK",
    "DESIGNS",
    "HELD_OUT",
    "LAB_CALIBRATION",
    "LAB_HELD_OUT",
    "LAB_SEEDS",
    "LAB_THIN",
    "PROTOCOL_CHECK",
    "RANDOM_CALIBRATION",
    "RANDOM_HELD_OUT",
    "THIN_MEMBRANE_FIELDS",
    "base_fields",
    "mould_aspect_ratios",
    "specimen_fields",
]

#: Cell pressures (kPa), membrane thicknesses (mm) and moduli (kPa) of the calibration grid.
_PRESSURES = (10.0, 40.0, 100.0)


def _grid(pressures, thicknesses, moduli=None) -> dict:
    """A ``membrax sweep`` grid: cell pressures (kPa), membrane thicknesses (mm) and, given, moduli (kPa)."""
    grid = {"cell_pressure_kpa": pressures, "membrane_thickness_mm": thicknesses}
    return grid if moduli is None else {**grid, "membrane_modulus_kpa": moduli}


#: group → (specimen fields, sweep grid). D/D_s = 1/5.7, 1/7.4, 1/10 (module docstring).
CALIBRATION = {
    "d6": ({"particles_across": 6, "layers": 10}, _grid(_PRESSURES, (1.0, 3.0, 5.0), (1400.0, 2800.0))),
    # The softest membrane without its thinnest: at 100 kPa a 1 mm sheet of 700 kPa is above its inflation
    # limit over the lattice's windows (82.7 kPa, membrax.config.inflation_ratio) and is refused.
    "d6_soft": ({"particles_across": 6, "layers": 10}, _grid(_PRESSURES, (3.0, 5.0), (700.0,))),
    # 2 mm rather than 1 mm: at 100 kPa a 1 mm sheet of 1400 kPa (α/D = 0.38, 0.60 of its inflation limit)
    # went non-finite in shearing on the 8-across specimen as the lattice's windows opened (docs/model.md).
    "d8": ({"particles_across": 8, "layers": 13}, _grid(_PRESSURES, (2.0, 5.0), (1400.0,))),
    "d10": ({"particles_across": 10, "layers": 17}, _grid(_PRESSURES, (2.0, 5.0), (1400.0,))),
}

#: Members off every grid line, for the held-out comparison (module docstring).
HELD_OUT = {
    "d7": ({"particles_across": 7, "layers": 12}, _grid((25.0, 70.0), (2.0, 4.0), (1000.0, 2000.0))),
}


#: The loose state's name in a random group's ``specimen`` fields (:func:`specimen_fields`).
_LOOSE = "loose"

#: group → (specimen fields, sweep grid) on random packings, the small protocol of :func:`base_fields`.
#: Equal 25 mm spheres in moulds 150, 200 and 250 mm across (D/D_s = 1/6, 1/8, 1/10, heights ≈ 1.3–1.7 D_s),
#: dense and loose; railway ballast scaled to a largest sieve of 25 mm = D_s/6 (d50 16.1 mm), dense and
#: loose, on the Table 1 grid (the same members as ``membrax reproduce --size small --packing random
#: --grading ballast [--state loose] --seeds 1``). Seed 0 everywhere: the seeds of the held-out members
#: are 1.
RANDOM_CALIBRATION = {
    "r6": ({"mould": (150.0, 250.0)}, _grid(_PRESSURES, (2.0, 3.0, 5.0), (1400.0, 2800.0))),
    # 1 mm sheets of 2800 kPa: 0.30 of their inflation limit at 100 kPa over 25 mm spheres' windows
    # (membrax.config.inflation_ratio); 1 mm of 1400 kPa is at 0.60, where FCC runs went non-finite.
    "r6_thin": ({"mould": (150.0, 250.0)}, _grid(_PRESSURES, (1.0,), (2800.0,))),
    "r6_soft": ({"mould": (150.0, 250.0)}, _grid(_PRESSURES, (3.0, 5.0), (700.0,))),
    "r6_loose": ({"mould": (150.0, 250.0), "state": _LOOSE}, _grid(_PRESSURES, (2.0, 5.0), (1400.0,))),
    "r8": ({"mould": (200.0, 270.0)}, _grid(_PRESSURES, (2.0, 5.0), (1400.0,))),
    "r10": ({"mould": (250.0, 320.0)}, _grid(_PRESSURES, (2.0, 5.0), (1400.0,))),
    "g6": ({"mould": (150.0, 250.0), "grading": "ballast"}, _grid(_PRESSURES, (2.5, 3.33, 5.0))),
    "g6_loose": (
        {"mould": (150.0, 250.0), "grading": "ballast", "state": _LOOSE},
        _grid(_PRESSURES, (2.5, 3.33, 5.0)),
    ),
}

#: Random members off every grid line of :data:`RANDOM_CALIBRATION` (σc 25 and 70 kPa, t_m 4 mm, E_m 1000
#: and 2000 kPa), on packings of seed 1 that no fit has seen: ballast-graded dense and loose in the 150 mm
#: mould, and equal spheres in a 175 mm one (D/D_s = 1/7). The shipped example record is one of them.
RANDOM_HELD_OUT = {
    "g6_held": (
        {"mould": (150.0, 250.0), "grading": "ballast", "seed": 1},
        _grid((25.0, 70.0), (4.0,), (2000.0,)),
    ),
    "g6_loose_held": (
        {"mould": (150.0, 250.0), "grading": "ballast", "state": _LOOSE, "seed": 1},
        _grid((25.0, 70.0), (4.0,), (1000.0,)),
    ),
    "r7_held": ({"mould": (175.0, 250.0), "seed": 1}, _grid((25.0, 70.0), (4.0,), (2000.0,))),
}

#: The loading rate and membrane resolution, checked rather than assumed: the r6 group's Table 1 members
#: (equal spheres, 150 mm mould, seed 0, t_m 2.5/3.33/5) run with the paper's protocol (I = 1e-3, membrane
#: edge D/5, :data:`membrax.reproduce.SIZES` ``"paper"``) instead of the small one; ``membrax reproduce
#: --size small --packing random`` runs the same members with the small protocol.
PROTOCOL_CHECK = {
    "r6_paper_protocol": (
        {"mould": (150.0, 250.0), "protocol": "paper"},
        _grid(_PRESSURES, (2.5, 3.33, 5.0)),
    ),
}

#: The training seeds of :data:`LAB_CALIBRATION` (its held-out members use others: 1 and 3).
LAB_SEEDS = (0, 2)


def _lab_group(mould, grid, seeds=LAB_SEEDS, **specimen):
    """One group per seed: ``{name_s<seed>: ({mould, protocol paper, seed, ...}, grid)}``."""
    return {seed: ({"mould": mould, "protocol": "paper", "seed": seed, **specimen}, grid) for seed in seeds}


#: The membrane law and contact of the thin soft members (1 mm of 700–1400 kPa): Gent's stiffening law
#: (J_m the default, natural rubber's) and sphere–triangle contact, with which 1 mm of 1400 kPa at 100 kPa
#: stays finite to 10 % strain on the 6- and 8-across FCC lattices at membrane edge D/3, where node contact
#: let the sheet pass between its nodes through the spheres (docs/model.md); at the paper's membranes Gent's
#: law gives Tables 2–3 within 0.03° of the default (docs/validation.md).
THIN_MEMBRANE_FIELDS = {"membrane_law": "gent", "membrane_contact_model": "faces"}

#: Two membranes per group and two moduli on the reference one: the Table 1 pressures.
_LAB_GRID = _grid(_PRESSURES, (2.0, 5.0), (1400.0,))

#: group → (specimen fields, sweep grid) at a laboratory's geometry and the paper's protocol (I = 1e-3,
#: membrane edge D/5): moulds of H/D = 2 (one group at 2.5), 150–300 mm across (D/D_s = 1/6–1/12 for equal
#: 25 mm spheres; ASTM D7181 and BS 1377-8 test at H/D 2–2.5), dense, medium (compaction friction 10°) and
#: loose, equal spheres, railway ballast and a uniform narrow grading (:data:`membrax.reproduce.
#: RANDOM_GRADINGS`, largest sieve D_s/6), seeds :data:`LAB_SEEDS`. The cost grows with the mould: a 300 ×
#: 600 mm member has about 3,000 spheres, a graded one a smaller time step. The groups stand cheapest first,
#: the order :func:`calibrate.grid.run_grid` runs them in, so that a sitting finishes (and archives) as many
#: as it can.
LAB_CALIBRATION = {
    f"{name}_s{seed}": item
    for name, groups in {
        # 1 mm of 2800 kPa: E_m t_m as 2 mm of 1400, half as thick (0.30 of the inflation limit at 100 kPa).
        "e6_thin": _lab_group((150.0, 300.0), _grid(_PRESSURES, (1.0,), (2800.0,))),
        "n6": _lab_group((150.0, 300.0), _LAB_GRID, grading="narrow"),
        "n6_loose": _lab_group((150.0, 300.0), _LAB_GRID, grading="narrow", state=_LOOSE),
        "e6_loose": _lab_group((150.0, 300.0), _LAB_GRID, state=_LOOSE),
        "e6_medium": _lab_group((150.0, 300.0), _LAB_GRID, state="medium"),
        "e6_h25": _lab_group((150.0, 375.0), _LAB_GRID),
        "e8": _lab_group((200.0, 400.0), _LAB_GRID),
        "g6": _lab_group((150.0, 300.0), _grid(_PRESSURES, (2.5, 5.0), (1400.0,)), grading="ballast"),
        "e6": _lab_group((150.0, 300.0), _grid(_PRESSURES, (2.0, 3.0, 5.0), (1400.0, 2800.0))),
        "e10": _lab_group((250.0, 500.0), _LAB_GRID),
        "e12": _lab_group((300.0, 600.0), _LAB_GRID),
    }.items()
    for seed, item in groups.items()
}

#: Members off every grid line of :data:`LAB_CALIBRATION`: seeds 1 and 3 (never trained on), σc 15–80 kPa,
#: thin (1.5 mm) and thick (4 mm) membranes, E_m 1000–2000 kPa, the medium state, H/D 2, D/D_s 1/7 and
#: 1/10, the narrow and the ballast gradings; scored through ``membrax correct`` as a user would.
LAB_HELD_OUT = {
    "e7_medium_held": (
        {"mould": (175.0, 350.0), "protocol": "paper", "seed": 1, "state": "medium"},
        _grid((15.0, 50.0, 80.0), (1.5, 4.0), (1400.0,)),
    ),
    "e10_held": (
        {"mould": (250.0, 500.0), "protocol": "paper", "seed": 3},
        _grid((25.0, 70.0), (1.5, 4.0), (2000.0,)),
    ),
    "n7_loose_held": (
        {"mould": (175.0, 350.0), "protocol": "paper", "seed": 1, "grading": "narrow", "state": _LOOSE},
        _grid((15.0, 50.0), (1.5, 4.0), (1000.0,)),
    ),
    "g6_medium_held": (
        {"mould": (150.0, 300.0), "protocol": "paper", "seed": 1, "grading": "ballast", "state": "medium"},
        _grid((25.0, 70.0), (1.5, 4.0), (1400.0,)),
    ),
}

#: The thin members' law and contact against the default's, at a laboratory's geometry: the e6_thin_s0
#: members (1 mm of 2800 kPa, within both laws' reach) run with :data:`THIN_MEMBRANE_FIELDS`, to set beside
#: the same members in :data:`LAB_CALIBRATION` (neo-Hookean, node contact).
CONTACT_CHECK = {
    "e6_thin_faces_s0": (
        {**LAB_CALIBRATION["e6_thin_s0"][0], "fields": THIN_MEMBRANE_FIELDS},
        LAB_CALIBRATION["e6_thin_s0"][1],
    ),
}

#: The thin soft corner at the laboratory's geometry (``--design lab_thin``, archived in
#: ``data/sweeps/lab_thin/``): 1 mm of 1400 kPa at 10, 40 and 100 kPa and of 700 kPa at 10 and 40 kPa
#: (E_m t_m/(σc D) 0.56–5.6; 1 mm of 700 kPa at 100 kPa is above even Gent's inflation limit and is refused),
#: as the e6 groups (dense equal spheres, 150 × 300 mm, seeds :data:`LAB_SEEDS`) with the law and contact of
#: :data:`THIN_MEMBRANE_FIELDS`. Not in :data:`LAB_CALIBRATION`: three of its ten members stopped on Gent's
#: lock in shearing (0.47 and 0.59 of the inflation limit; docs/calibration.md).
LAB_THIN = {
    f"{name}_s{seed}": item
    for name, groups in {
        "e6_thin_soft": _lab_group(
            (150.0, 300.0), _grid(_PRESSURES, (1.0,), (1400.0,)), fields=THIN_MEMBRANE_FIELDS
        ),
        "e6_thin_softest": _lab_group(
            (150.0, 300.0), _grid((10.0, 40.0), (1.0,), (700.0,)), fields=THIN_MEMBRANE_FIELDS
        ),
    }.items()
    for seed, item in groups.items()
}

#: ``python -m calibrate.grid --design NAME``'s designs.
DESIGNS = {
    "fcc": CALIBRATION,
    "fcc_held_out": HELD_OUT,
    "random": RANDOM_CALIBRATION,
    "random_held_out": RANDOM_HELD_OUT,
    "protocol_check": PROTOCOL_CHECK,
    "lab": LAB_CALIBRATION,
    "lab_held_out": LAB_HELD_OUT,
    "lab_thin": LAB_THIN,
    "contact_check": CONTACT_CHECK,
}


def mould_aspect_ratios(groups) -> dict:
    """{group: its mould's height over diameter} for the random groups of ``groups`` (FCC ones have none).

    The nominal H/D_s of a design's specimens, for a correction fitted before the sweeps' heights were
    read (:func:`calibrate.datasets.aspect_ratios` reads them from ``sweep.nc``): a compacted specimen
    comes out within a few per cent of its mould.
    """
    return {
        name: specimen["mould"][1] / specimen["mould"][0]
        for name, (specimen, _) in groups.items()
        if "mould" in specimen
    }


def specimen_fields(specimen: dict) -> dict:
    """The configuration fields of a group's specimen: :func:`base_fields` and the group's own.

    An FCC group's fields are configuration fields already (``particles_across``, ``layers``). A random
    group's: ``mould`` (diameter, height) mm, ``grading`` (``"equal"`` or ``"ballast"``, scaled to D_s/6 as
    :func:`membrax.reproduce.random_fields`), ``state`` (``"dense"``/``"loose"``,
    :data:`membrax.defaults.COMPACTION_FRICTION_DEG`), ``seed`` (the packing seed, default 0) and
    ``protocol`` (``"small"``, the default, or ``"paper"``: :data:`membrax.reproduce.SIZES`), and ``fields``
    (configuration fields set over those, e.g. the membrane law of :data:`THIN_MEMBRANE_FIELDS`).
    """
    if "mould" not in specimen:
        return {**base_fields(), **specimen}
    from membrax.reproduce import random_fields

    fields = random_fields(
        specimen.get("protocol", "small"),
        specimen.get("grading", "equal"),
        specimen.get("state", "dense"),
        mould_mm=specimen["mould"],
    )
    return {**fields, "packing_seed": specimen.get("seed", 0), **specimen.get("fields", {})}


def base_fields() -> dict:
    """The configuration fields every group shares: the small preset of ``membrax reproduce``.

    A function, not a constant, so that importing this module does not import JAX (``split_cpu_devices``
    must run first).
    """
    from membrax.reproduce import SIZES

    return dict(SIZES["small"])
