"""The paper's test as membrax's defaults, in SI: the one source the configuration and the simulator share.

Contract. Plain constants (no JAX, no imports from membrax): the inputs of the reference study that are
also membrax's defaults (its §3 and Table 1), the membrane's material laws (latex's ν, the stretching
laws), the shearing's start-up ramp, and the unbalanced-force ratio that ends consolidation.
:class:`membrax.config.TriaxialConfig` derives its laboratory-unit field defaults from these
(``membrane_modulus_kpa = MEMBRANE_MODULUS / 1e3``), the cells (:mod:`membrax.triaxial`) and the
membrane (:mod:`membrax.membrane.coupled`) take them as their SI defaults, and :mod:`membrax.paper` prints
them beside the paper's tables; nothing below the configuration imports the configuration
(``tests/test_architecture.py``).
"""

from __future__ import annotations

__all__ = [
    "CONSOLIDATION_TOLERANCE",
    "DAMPING_FRAME",
    "DAMPING_FRAMES",
    "FRICTION_ANGLE_DEG",
    "GENT_LOCK_FRACTION",
    "GENT_LOCKING_JM",
    "LATEX_DENSITY",
    "LATEX_POISSON_RATIO",
    "LAYERS",
    "MEMBRANE_CONTACT_MODELS",
    "MEMBRANE_LAWS",
    "MEMBRANE_MODULUS",
    "PARTICLES_ACROSS",
    "PARTICLE_DIAMETER",
    "SHEAR_RAMP_STRAIN",
    "STRETCHING_MODELS",
    "default_consolidation_tolerance",
]

#: Sphere diameter D, m: the paper's 25 mm granite spheres (its §3).
PARTICLE_DIAMETER = 0.025
#: Spheres across the specimen: the paper's 10 (a 250 mm specimen).
PARTICLES_ACROSS = 10
#: FCC layers of the specimen: the paper's 25 (about 500 mm high).
LAYERS = 25
#: Interparticle friction angle φ_μ, degrees: the paper's 25°.
FRICTION_ANGLE_DEG = 25.0
#: Latex membrane Young's modulus E_m, Pa: the paper's 1400 kPa (its Table 1).
MEMBRANE_MODULUS = 1.4e6
#: Latex density, kg/m³ (920–1000; the issue's "about 1000").
LATEX_DENSITY = 1000.0

#: ν of latex, an incompressible rubber: the membrane's forces and bending rigidity
#: (:func:`membrax.membrane.energies.nodal_forces`).
LATEX_POISSON_RATIO = 0.5
#: The membrane's stretching laws (:func:`membrax.membrane.energies.stretching_energy`), in the order the
#: compiled kernel numbers them (``membrane_forces.cc``).
STRETCHING_MODELS = ("neo_hookean", "svk", "gent")
#: The configuration's spelling of each stretching law (``membrane_law``) → the simulator's: the one map.
MEMBRANE_LAWS = {"neo-hookean": "neo_hookean", "gent": "gent", "svk": "svk"}
#: Gent's locking constant J_m, dimensionless: the largest I₁ − 3 the rubber's chains allow. 97.2 is Gent's
#: fit of Treloar's natural-rubber data (Gent 1996, Rubber Chem. Technol. 69, 59–61) [U: the value as later
#: reviews of the Gent model quote it, not checked in the source]; latex is a natural rubber. Equibiaxially it
#: locks at λ = 7.08 (2λ² + λ⁻⁴ − 3 = J_m).
GENT_LOCKING_JM = 97.2
#: The fraction of J_m past which the Gent energy is continued by its quadratic extension in I₁ − 3, so that
#: forces stay finite (:func:`membrax.membrane.energies.stretching_energy`); a coupled step that stretches a
#: triangle past it sets ``ErrorCode.MEMBRANE_LOCKED`` and the run stops there.
GENT_LOCK_FRACTION = 0.9
#: Where the spheres meet the membrane (:func:`membrax.membrane.coupled.membrane_dem`): its nodes (the
#: paper's "node–particle contact", the default) or its faces, edges and nodes
#: (:mod:`membrax.membrane.face_contact`).
MEMBRANE_CONTACT_MODELS = ("nodes", "faces")

#: Axial strain at which the platens reach full speed after a linear ramp from rest
#: (:meth:`membrax.triaxial.membrane_cell.MembraneTest.start_shear`; YADE's
#: ``UniaxialStrainer.initAccelTime`` does the same). A step change of platen velocity sends a compression
#: wave through the specimen, and the dense lattice, whose peak is its elastic limit at ~0.008 % strain,
#: reports the wave's overshoot as its peak: at paper size, 10 kPa, 5 mm, I = 1e-3, no ramp gives φ'ext/int
#: 46.9/46.1°. The ramp makes the approach to the peak quasi-static: at the peak the platens move at
#: √(ε_peak/ε_ramp) of full speed (9 % for 1e-2). Measured at paper size (float32, same consolidated
#: state): ε_ramp = 1e-3 gives 41.19/40.74° at I = 1e-3 and 40.69/40.30° at I/2 (0.5° apart); ε_ramp = 1e-2
#: gives 40.55/40.17° and 40.43/40.06° (0.12° apart), hence the default. The ramp lasts 2 ε_ramp/ε̇, about
#: 300 wave transit times H/c at paper size (``MembraneTest.ramp_transit_ratio``), and delays every later
#: strain by ε_ramp/ε̇ (1 % of strain's worth of steps).
SHEAR_RAMP_STRAIN = 1.0e-2

#: The velocities Cundall's local damping (and the viscous term) act on, spheres and membrane nodes alike
#: (:class:`membrax.spheres.integrate.DampingParams`): ``"affine"``, the velocity relative to the affine field
#: of the strain-controlled walls, v_ref = (0, 0, v_b + (v_t − v_b)(z − z_b)/(z_t − z_b)) between the platens
#: while they shear the specimen (:func:`membrax.spheres.walls.affine_velocity`; servo-held walls count as at
#: rest), or ``"absolute"``, the velocity itself (the paper's and PFC's practice). The two are the same law
#: while the platens stand still or are servo-held (consolidation: the same bits). While the platens close,
#: absolute damping drags every sphere against the affine motion and the platens carry the drag. Measured
#: (``examples/damping_artefact.py``, float32, 10 kPa, I = 1e-3, records over 1–2 % axial strain): in a rigid
#: box, both platens closing, the platens' stress ran 1.82 % above the Love–Weber stress at paper size (10 ×
#: 25 spheres) and 0.67 % on 6 × 10, against 0.64 % and 0.34 % with the affine frame (what is left is the
#: damping of the non-affine motion); the top platen alone closing, the top platen's stress 4.60 % and 1.44 %
#: above, against 0.66 % and 0.38 %. In a membrane cell the membrane's nodes carried 0.61 % of σc onto the
#: ram, against 0.15 %. Absolute-velocity damping gave 3.6–5.1 % (both platens closing) worth 0.6–1.0° of
#: wall-based φ', from membrax and an independent DEM code; a membrane calibration learning from the ram would
#: count it as membrane. Periodic codes damp the fluctuation about the cell's homogeneous deformation for the
#: same reason (YADE's ``NewtonIntegrator``), hence the default.
DAMPING_FRAME = "affine"
#: The accepted values of :data:`DAMPING_FRAME`.
DAMPING_FRAMES = ("affine", "absolute")

#: The mean stress a random specimen is compacted to in its mould, Pa (:mod:`membrax.spheres.compaction`):
#: the paper's lowest cell pressure, and about the 15–20 kPa suction under which a laboratory prepares a
#: specimen in its mould. Fixed, not the test's cell pressure, so that every member of a sweep over cell
#: pressure starts from the same specimen, as a laboratory's series would.
COMPACTION_STRESS = 1.0e4

#: Interparticle friction during a random specimen's compaction, degrees, by packing state: none gives the
#: densest packing (solid fraction ≈ 0.639 for equal spheres, Agnolin & Roux 2007); tan⁻¹ 0.5 a loose one
#: (whole-specimen solid fraction 0.518 against 0.569 dense in the 150 × 250 mm demo mould,
#: docs/validation.md); 10° (μ = 0.18) a medium-dense one between them, the laboratory's usual state. The
#: test's own friction is set after compaction (YADE's and PFC's practice).
COMPACTION_FRICTION_DEG = {"dense": 0.0, "medium": 10.0, "loose": 26.565051177077994}

#: The unbalanced-force ratio that ends consolidation when none is given, by cell (``"rigid"`` walls, a
#: ``"membrane"`` or the ``"periodic"`` element) and precision (float64 or not): the one rule of
#: ``RigidWallTest.consolidate``, ``MembraneTest.consolidate``, ``PeriodicTest.consolidate`` and a
#: configuration's ``consolidation_tolerance = 0``. float32's force
#: round-off floors the ratio at ~2e-3 in a rigid cell (a 25 mm branch vector resolves 2e-9 m, 0.1 % of a
#: contact overlap at 40 kPa, summed over 12 contacts) and at 1.1e-2 / 3e-3 / 1.2e-3 with the membrane at
#: 10 / 40 / 100 kPa (paper size), hence the looser float32 values.
CONSOLIDATION_TOLERANCE = {
    ("rigid", True): 1e-3,
    ("rigid", False): 5e-3,
    ("membrane", True): 2e-3,
    ("membrane", False): 2e-2,
    # The periodic element's float32 floor: 1.2e-3 to 1.6e-3 over 200,000 steps for 100 dense spheres at
    # 40 kPa (2026-11-29), so the rigid cell's 5e-3; a loose packing of 150 at 100 kPa passes 1e-3.
    ("periodic", True): 1e-3,
    ("periodic", False): 5e-3,
}


def default_consolidation_tolerance(cell: str, float64: bool) -> float:
    """The default unbalanced-force ratio ending consolidation (:data:`CONSOLIDATION_TOLERANCE`).

    Args:
      cell: ``"rigid"``, ``"membrane"`` or ``"periodic"``.
      float64: whether the simulation runs in float64.

    Raises:
      ValueError: an unknown cell.
    """
    if cell not in ("rigid", "membrane", "periodic"):
        raise ValueError(f"cell = {cell!r}; it must be 'rigid', 'membrane' or 'periodic'.")
    return CONSOLIDATION_TOLERANCE[cell, bool(float64)]
