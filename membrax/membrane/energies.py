"""The membrane's laws: stretching, bending and cell-pressure energies, their nodal forces, its masses.

Contract. Every function takes the current node positions (N, 3) and a :class:`MembraneMesh`
(:mod:`membrax.membrane.mesh`: topology, rest geometry and the kinematics the laws read — Green strains,
hinge angles, enclosed volume) with the material parameters, and returns an energy (J), nodal forces (N)
or node masses (kg). They are pure ``jnp`` functions, jittable and differentiable with respect to the
positions and the parameters; conservative nodal forces are ``-jax.grad`` of :func:`total_energy`
(:func:`nodal_forces`, on the CPU a compiled kernel held to that definition). SI units throughout: m, Pa,
N, J, kg.

Energies (reference: ``shared/reference/membrane-corrections.md`` §11):

- stretching: constant-strain triangles (CST) with an incompressible neo-Hookean or Gent law or a
  St Venant–Kirchhoff law (:func:`stretching_energy`);
- bending: Discrete Shells (Grinspun et al. 2003) calibrated to the plate rigidity, k_b = D/6
  (:func:`bending_energy`);
- cell pressure: the load potential +p V, V the volume enclosed by the band closed with two flat caps
  (:func:`membrax.membrane.mesh.enclosed_volume`, :func:`pressure_energy`).

Stiffening near the Gent lock (:func:`gent_tangent_ratio`, :func:`stable_locking_ratio`): the Gent law's
tangent stiffness grows without bound toward the lock, so an explicit step chosen at rest becomes unstable
before the lock is reached; the coupled step checks the closest approach against the step's limit
(:mod:`membrax.membrane.coupled`, ``ErrorCode.MEMBRANE_STIFFENED``).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp

from membrax import native
from membrax.defaults import GENT_LOCK_FRACTION, GENT_LOCKING_JM, LATEX_POISSON_RATIO, STRETCHING_MODELS
from membrax.membrane import _kernels
from membrax.membrane.mesh import (
    MembraneMesh,
    dihedral_angle,
    enclosed_volume,
    enclosed_volume_of,
    gathered_corners,
    gathered_hinges,
    green_strain,
    triangle_invariants,
)

__all__ = [
    "stretching_energy",
    "locking_ratio",
    "gent_equibiaxial_stretch",
    "gent_tangent_ratio",
    "stable_locking_ratio",
    "bending_rigidity",
    "bending_energy",
    "pressure_energy",
    "total_energy",
    "nodal_forces",
    "reference_nodal_forces",
    "lumped_mass",
]


def stretching_energy(
    position,
    mesh: MembraneMesh,
    modulus,
    thickness,
    model="neo_hookean",
    poisson_ratio=0.5,
    locking_jm=GENT_LOCKING_JM,
):
    """In-plane strain energy of the membrane with constant-strain triangles, J.

    Per triangle, with D_m the rest edge matrix in the triangle's plane and D_s = [x₂ − x₁, x₃ − x₁] (3 × 2):
    F = D_s D_m⁻¹, C = FᵀF, E = (C − I)/2 (reference §11; standard finite elements), and, with
    I₁ − 3 = tr C + 1/det C − 3 (incompressible: λ₃² = 1/det C, thickness t = t₀/√det C),

    - ``"neo_hookean"`` (incompressible, plane stress): W = t₀ A₀ (μ/2)(I₁ − 3), μ = E_m/3;
    - ``"gent"`` (incompressible, plane stress; Gent 1996, Rubber Chem. Technol. 69, 59–61):
      W = −t₀ A₀ (μ J_m/2) ln(1 − (I₁ − 3)/J_m), μ = E_m/3, J_m the locking constant: the chains' limited
      extensibility, the stress growing without bound as I₁ − 3 → J_m. It tends to the neo-Hookean law as
      J_m → ∞ (relative difference (I₁ − 3)/(2 J_m) in the energy);
    - ``"svk"`` (St Venant–Kirchhoff, plane stress): W = t₀ A₀ [μ tr(E²) + (λ*/2)(tr E)²],
      μ = E_m/(2(1+ν)), λ* = E_m ν/(1−ν²).

    Small strain: all three give plane stress of Young's modulus E_m, the two rubbers with Poisson's ratio
    ν = ½ (incompressible: at small strain I₁ − 3 = 4(tr E)² − 4 det E = 4(ε₁₁² + ε₂₂² + ε₁₁ε₂₂ + ε₁₂²),
    so (μ/2)(I₁ − 3) with μ = E_m/3 is E_m/(2(1 − ν²)) (ε₁₁² + ε₂₂² + 2ν ε₁₁ε₂₂) + 2G ε₁₂² at ν = ½), SVK
    with its ``poisson_ratio``. So E_m means the same in all three.

    Why neo-Hookean: latex is a rubber, near incompressible, and the membrane reaches tens of percent
    strain where bulging; the neo-Hookean law is the simplest finite-strain rubber law. It has an inflation
    limit (:func:`membrax.theory.membrane_limit_pressure`), which real latex passes by stiffening as its
    chains near full extension: Gent's law adds that stiffening with one constant. SVK is kept for small
    strains (below ~10 %) and other ν.

    The Gent lock. Past I₁ − 3 = f J_m (f = :data:`membrax.defaults.GENT_LOCK_FRACTION`) the energy is
    continued by its quadratic extension in I₁ − 3, so that it stays finite and its forces finite and
    continuous (W is C² in I₁ − 3) however far a triangle is stretched: with s = (I₁ − 3)/J_m,
    W/(t₀ A₀ μ J_m/2) = −ln(1 − s) below f and −ln(1 − f) + (s − f)/(1 − f) + (s − f)²/(2(1 − f)²) above.
    The continued energy is not Gent's: the coupled step sets ``ErrorCode.MEMBRANE_LOCKED`` when a triangle
    passes f (:func:`locking_ratio`), and the run stops there with a :class:`membrax.errors.SimulationError`.

    Wrinkling: a membrane cannot carry compression. Here compression resistance comes from the bending
    energy (:func:`bending_energy`), which lets the mesh wrinkle at its own resolution; a tension-field
    (relaxed) energy is not implemented, so wrinkles finer than the mesh are not resolved.

    The rubbers' bracket I₁ − 3 is evaluated through E as (4(tr E)² + 8 tr E det E − 4 det E)/det C, an exact
    rewriting that avoids the cancellation of tr C + 1/det C − 3 at small strain (≈ 10 % error in float32
    at 10⁻³ strain otherwise).

    Args:
      position: (N, 3) current node positions, m.
      mesh: the membrane.
      modulus: E_m, Pa (scalar; traced, differentiable).
      thickness: t₀, m (scalar; traced, differentiable).
      model: ``"neo_hookean"``, ``"gent"`` or ``"svk"`` (static).
      poisson_ratio: ν of the SVK law (the rubbers are incompressible).
      locking_jm: J_m of the Gent law, dimensionless, > 0 (traced, differentiable; unused by the others).

    Returns:
      Scalar energy, J.
    """
    return _stretching_energy_of(
        green_strain(position, mesh), mesh, modulus, thickness, model, poisson_ratio, locking_jm
    )


def _first_invariant_excess(strain):
    """I₁ − 3 = tr C + 1/det C − 3 of incompressible triangles from their Green strain (E₁₁, E₂₂, E₁₂).

    Evaluated as (4(tr E)² + 8 tr E det E − 4 det E)/det C, det C = 1 + 2 tr E + 4 det E: exact, and free
    of the cancellation of the direct form at small strain.
    """
    e11, e22, e12 = strain
    trace = e11 + e22
    determinant = e11 * e22 - e12 * e12
    det_c = 1.0 + 2.0 * trace + 4.0 * determinant
    return (4.0 * trace * trace + 8.0 * trace * determinant - 4.0 * determinant) / det_c


def _gent_stiffening_integral(ratio):
    """φ(s) = −ln(1 − s), continued past s = f by its quadratic extension (:func:`stretching_energy`).

    φ'(s) = 1/(1 − s) below f and 1/(1 − f) + (s − f)/(1 − f)² above: the factor by which Gent's stress
    exceeds the neo-Hookean one at the same strain.

    The two pieces are chosen by one comparison: ``jnp.minimum`` and ``jnp.maximum`` split their derivative
    at a tie, which gave φ'' = 50 instead of 100 at s = f exactly, and under ``jit`` (where the tie can be
    decided differently in the two) a stress factor of up to 20 instead of 10 for a triangle within an ulp
    of f. The values are the same.
    """
    past_lock = ratio > GENT_LOCK_FRACTION
    below = jnp.where(past_lock, GENT_LOCK_FRACTION, ratio)
    past = jnp.where(past_lock, ratio - GENT_LOCK_FRACTION, 0.0)
    slack = 1.0 - GENT_LOCK_FRACTION
    return -jnp.log1p(-below) + past / slack + 0.5 * (past / slack) ** 2


def _stretching_energy_of(strain, mesh: MembraneMesh, modulus, thickness, model, poisson_ratio, locking_jm):
    """:func:`stretching_energy` from the triangles' Green–Lagrange strain (E₁₁, E₂₂, E₁₂), (T,) each."""
    if model not in STRETCHING_MODELS:
        raise ValueError(f"model must be one of {STRETCHING_MODELS}, got {model!r}")
    e11, e22, e12 = strain
    trace = e11 + e22
    if model == "neo_hookean":
        density = (modulus / 6.0) * _first_invariant_excess(strain)  # (μ/2)(I₁ − 3) with μ = E/3
    elif model == "gent":
        ratio = _first_invariant_excess(strain) / locking_jm
        density = (modulus / 6.0) * locking_jm * _gent_stiffening_integral(ratio)  # −(μ J_m/2) ln(1 − s)
    else:
        shear = modulus / (2.0 * (1.0 + poisson_ratio))
        lame = modulus * poisson_ratio / (1.0 - poisson_ratio * poisson_ratio)
        density = shear * (e11 * e11 + e22 * e22 + 2.0 * e12 * e12) + 0.5 * lame * trace * trace
    return thickness * jnp.sum(mesh.reference_area * density)


def locking_ratio(position, mesh: MembraneMesh, locking_jm):
    """The membrane's closest approach to Gent's lock: the largest (I₁ − 3)/J_m over its triangles.

    Past :data:`membrax.defaults.GENT_LOCK_FRACTION` the Gent energy is its continuation, no longer Gent's
    (:func:`stretching_energy`); the coupled step checks it every ``LOCK_CHECK_EVERY`` steps
    (:func:`membrax.membrane.stability.locked_bit`, ``ErrorCode.MEMBRANE_LOCKED``).

    Args:
      position: (N, 3) node positions, m.
      mesh: the membrane.
      locking_jm: J_m, dimensionless.
    """
    return jnp.max(_first_invariant_excess(green_strain(position, mesh))) / locking_jm


def _gent_stiffening_slopes(ratio):
    """φ'(s) and φ''(s) of :func:`_gent_stiffening_integral`, continued past f as the energy is."""
    slack = 1.0 - GENT_LOCK_FRACTION
    below = 1.0 - jnp.minimum(ratio, GENT_LOCK_FRACTION)
    past = jnp.maximum(ratio - GENT_LOCK_FRACTION, 0.0)
    return 1.0 / below + past / (slack * slack), 1.0 / (below * below)


def gent_equibiaxial_stretch(ratio, locking_jm):
    """The equibiaxial stretch λ ≥ 1 at which Gent's s = (I₁ − 3)/J_m equals ``ratio`` (jittable).

    Incompressible, λ₁ = λ₂ = λ, λ₃ = λ⁻²: I₁ − 3 = 2λ² + λ⁻⁴ − 3 = s J_m, so u = λ² is the largest root of
    the cubic 2u³ − (3 + s J_m) u² + 1 = 0. With a = 3 + s J_m and u = a/6 + t it is t³ + p t + q = 0,
    p = −a²/12, q = ½ − a³/108, whose largest root is Viète's
    t = 2 √(−p/3) cos(⅓ arccos((3q/2p) √(−3/p))) (three real roots: a ≥ 3).

    Args:
      ratio: s, dimensionless, >= 0 (array or scalar).
      locking_jm: J_m, > 0.
    """
    a = 3.0 + ratio * locking_jm
    p = -a * a / 12.0
    q = 0.5 - a * a * a / 108.0
    cosine = jnp.clip((1.5 * q / p) * jnp.sqrt(-3.0 / p), -1.0, 1.0)
    squared = a / 6.0 + 2.0 * jnp.sqrt(-p / 3.0) * jnp.cos(jnp.arccos(cosine) / 3.0)
    return jnp.sqrt(squared)


def gent_tangent_ratio(ratio, locking_jm):
    """k_t(s)/k_0: Gent's equibiaxial tangent stiffness at s = (I₁ − 3)/J_m over its value at rest.

    With the energy density w(λ) = (μ J_m/2) φ(s) of an equibiaxial stretch λ (:func:`stretching_energy`;
    λ from :func:`gent_equibiaxial_stretch`, I₁ − 3 = 2λ² + λ⁻⁴ − 3 = s J_m) the tangent is

        k_t = d²w/dλ² = (μ/2) [φ''(s) (dI₁/dλ)²/J_m + φ'(s) d²I₁/dλ²],
        dI₁/dλ = 4(λ − λ⁻⁵),  d²I₁/dλ² = 4 + 20 λ⁻⁶,

    and k_0 = 12 μ (λ = 1), so k_t/k_0 = [16 φ''(s) (λ − λ⁻⁵)²/J_m + φ'(s)(4 + 20 λ⁻⁶)]/24, with
    φ' = 1/(1 − s), φ'' = 1/(1 − s)² (derived here from Gent 1996; past s = f the continued energy's
    φ' = 1/(1 − f) + (s − f)/(1 − f)², φ'' = 1/(1 − f)²). At J_m = 97.2 it is 0.242 at s = 0.1, 1.041 at
    0.5, 3.262 at 0.7 and 32.69 at 0.9: the rubber first softens (the neo-Hookean part), then stiffens
    without bound toward the lock.

    Why it bounds the step. The mesh's stiffness is K = Bᵀ (∂²w/∂F²) B with the rest geometry's B and the
    rest masses, so its largest frequency scales with the largest eigenvalue of the membrane's elasticity
    tensor ∂²w/∂F² (F the 3 × 2 deformation gradient, the stress's geometric terms included). At an
    equibiaxial stretch that eigenvalue is the area mode's, and k_t/k_0 is its ratio to rest. Among plane
    states from uniaxial to equibiaxial tension (λ₂ from λ₁^(−1/2) to λ₁) at one s, the equibiaxial one
    has the largest wherever it exceeds 1.15 (s ≥ 0.52 at J_m = 97.2; below, every state is softer
    than at rest); ``tests/test_membrane_laws.py`` checks both against the Hessian of the energy. So
    Δt_crit,membrane(s) ≥ Δt_crit,membrane(0) / √(k_t(s)/k_0) for a membrane whose largest s is s: on a
    flat patch held at λ(s) its M⁻¹K's largest eigenvalue grows by 0.94, 0.88 and 0.80 of k_t/k_0 at
    s = 0.6, 0.7 and 0.85 (the rest mesh's highest mode is not purely the area mode).

    Args:
      ratio: s, dimensionless, >= 0 (traced, any shape).
      locking_jm: J_m, > 0 (traced).

    Returns:
      k_t/k_0, dimensionless, the dtype of the inputs.
    """
    stretch = gent_equibiaxial_stretch(ratio, locking_jm)
    inverse = stretch**-2  # λ⁻²
    slope, curvature = _gent_stiffening_slopes(ratio)
    first = stretch * (1.0 - inverse**3)  # λ − λ⁻⁵
    return (16.0 * curvature * first * first / locking_jm + slope * (4.0 + 20.0 * inverse**3)) / 24.0


def stable_locking_ratio(tangent_limit, locking_jm) -> float:
    """s_stable: the largest s = (I₁ − 3)/J_m whose tangent ratio stays within ``tangent_limit`` (host).

    s_stable solves k_t(s)/k_0 = r_max on the stiffening branch of :func:`gent_tangent_ratio` (the ratio
    first falls below 1, then rises without bound: s_stable is the crossing past its minimum), by bisection
    in float64 to 1e-12. r_max is the step's limit, (Δt_crit,mesh/Δt)² − (Δt_crit,mesh/Δt_crit,contact)²
    (:func:`membrax.membrane.stability.membrane_tangent_limit`); with dt_safety 0.5 and negligible contact
    r_max = 4, s_stable = 0.73 at J_m = 97.2. Returns ``inf`` for an infinite limit and 0 for a limit below
    the ratio's minimum (no stretch is safe).

    Args:
      tangent_limit: r_max, dimensionless.
      locking_jm: J_m, > 0.
    """
    import numpy as np

    limit, jm = float(tangent_limit), float(locking_jm)
    if math.isinf(limit):
        return math.inf

    def ratio_at(s):
        return float(gent_tangent_ratio(np.float64(s), np.float64(jm)))

    grid = np.linspace(0.0, GENT_LOCK_FRACTION, 181)
    low = float(grid[int(np.argmin([ratio_at(s) for s in grid]))])
    if ratio_at(low) > limit:
        return 0.0
    high = low + 0.1
    while ratio_at(high) <= limit:
        high = low + 2.0 * (high - low)
    while high - low > 1e-12:
        middle = 0.5 * (low + high)
        low, high = (middle, high) if ratio_at(middle) <= limit else (low, middle)
    return low


def bending_rigidity(modulus, thickness, poisson_ratio=0.5):
    """Plate bending rigidity D = E t³ / (12 (1 − ν²)), N·m (Kirchhoff plate theory)."""
    return modulus * thickness**3 / (12.0 * (1.0 - poisson_ratio * poisson_ratio))


def bending_energy(position, mesh: MembraneMesh, modulus, thickness, poisson_ratio=0.5):
    """Discrete Shells bending energy (Grinspun, Hirani, Desbrun & Schröder 2003), J.

        E_b = Σ_{interior edges e} k_b · 3|ē_e|²/Ā_e · (θ_e − θ̄_e)²,   k_b = D/6,   D = E t³/(12(1 − ν²)),

    ē_e, Ā_e the rest edge length and summed rest area of the two adjacent triangles, θ_e the angle
    between their normals (θ̄_e at rest). k_b = D/6 is calibrated so that a near-equilateral mesh rolled
    into a cylinder of radius R stores the Kirchhoff energy (D/2)·Area/R² (reference §11: the sum tends to
    3.00·Area/R² for both edge orientations). On doubly curved shapes the match is only approximate (a
    sphere gives ≈ 1.02 × the Kirchhoff energy with ν = 0, reference §11).

    Args:
      position: (N, 3) current node positions, m.
      mesh: the membrane.
      modulus: E_m, Pa.
      thickness: t_m, m.
      poisson_ratio: ν in D (½ for latex).

    Returns:
      Scalar energy, J.
    """
    angle = dihedral_angle(gathered_hinges(position, mesh))
    stiffness = bending_rigidity(modulus, thickness, poisson_ratio) / 6.0
    change = angle - mesh.rest_dihedral
    return stiffness * jnp.sum(mesh.edge_weight * change * change)


def pressure_energy(position, mesh: MembraneMesh, cell_pressure):
    """Potential of the cell pressure, Π_p = +p V, J (reference §11).

    The cell fluid does work −p dV on the specimen, so its potential is +p V and the nodal force
    −p ∂V/∂x = −p Σ_f A_f n_f/3 points inward for p > 0 (a negative p is an internal pressure). On the end
    rings the force includes the cap share; with the rings clamped to the platens it is a reaction.

    Args:
      position: (N, 3) node positions, m.
      mesh: the membrane (band and end rings).
      cell_pressure: p, Pa.
    """
    return cell_pressure * enclosed_volume(position, mesh)


def total_energy(
    position,
    mesh: MembraneMesh,
    modulus,
    thickness,
    cell_pressure,
    poisson_ratio=0.5,
    model="neo_hookean",
    bending_factor=1.0,
    locking_jm=GENT_LOCKING_JM,
):
    """Stretching + bending + pressure potential of the membrane, J (see the three terms).

    ``bending_factor`` scales the bending energy: 1 is the plate's E t³/12(1 − ν²), 0 a pure membrane
    (a mesh with no bending stiffness, which may be what the paper's finite-difference mesh was).
    ``locking_jm`` is the Gent law's J_m (:func:`stretching_energy`).
    """
    # One pass over the triangles gives both the strain and the band's volume term.
    *strain, triple = triangle_invariants(gathered_corners(position, mesh), mesh.reference_inverse)
    return (
        _stretching_energy_of(strain, mesh, modulus, thickness, model, poisson_ratio, locking_jm)
        + bending_factor * bending_energy(position, mesh, modulus, thickness, poisson_ratio)
        + cell_pressure * enclosed_volume_of(jnp.sum(triple) / 6.0, position, mesh)
    )


def nodal_forces(
    position,
    mesh: MembraneMesh,
    modulus,
    thickness,
    cell_pressure,
    poisson_ratio=LATEX_POISSON_RATIO,
    model="neo_hookean",
    bending_factor=1.0,
    locking_jm=GENT_LOCKING_JM,
):
    """Conservative nodal forces −∂(total energy)/∂x, (N, 3), N.

    On the CPU, in float32 or float64, the forces come from a compiled kernel (:mod:`membrax.native`,
    ``membrane_forces.cc``) that evaluates the same formulas in one pass over the triangles and hinges,
    and skips the hinges when ``bending_factor`` is 0. The JAX expression −∇(total energy) is used
    everywhere else and is the definition the tests hold the kernel to (agreement to round-off). Reverse
    mode (``jax.grad``, ``jax.vjp``) runs a compiled backward kernel on the CPU
    (``membrane_forces_backward``): the forces are −∇Φ, so their Jacobian is symmetric and Jᵀū is the
    directional derivative J ū, evaluated on dual numbers, with ū·∂F/∂(E_m, t_m, p, ν, f_b, J_m) from the
    same pass; it gives the JAX expression's derivatives to round-off (``tests/test_native.py``). When the
    mesh's rest geometry is differentiated, the JAX expression's own derivatives are used.
    """
    if model not in STRETCHING_MODELS:
        raise ValueError(f"model must be one of {STRETCHING_MODELS}, got {model!r}")
    position = jnp.asarray(position)
    args = (position, mesh, modulus, thickness, cell_pressure, poisson_ratio, bending_factor, locking_jm)
    if native.enabled_for(position.dtype):
        return _COMPILED_NODAL_FORCES[model](*args)
    return reference_nodal_forces(*args[:7], model, locking_jm)


def reference_nodal_forces(
    position,
    mesh,
    modulus,
    thickness,
    cell_pressure,
    poisson_ratio,
    bending_factor,
    model,
    locking_jm=GENT_LOCKING_JM,
):
    """−∇(total energy) by ``jax.grad``: the definition of :func:`nodal_forces`."""
    return -jax.grad(total_energy)(
        position, mesh, modulus, thickness, cell_pressure, poisson_ratio, model, bending_factor, locking_jm
    )


def _reference_of(model):
    """:func:`reference_nodal_forces` of one law, J_m last (as the kernel takes it) and optional."""

    def reference(*args):
        return reference_nodal_forces(*args[:7], model, *args[7:])

    return reference


_COMPILED_NODAL_FORCES = {
    model: native.with_reference(
        functools.partial(_kernels.nodal_forces_kernel, model=model),
        _reference_of(model),
        functools.partial(_kernels.nodal_forces_backward, model=model),
    )
    for model in STRETCHING_MODELS
}


def lumped_mass(mesh: MembraneMesh, thickness, density=1000.0):
    """Node masses, (N,), kg: each triangle's rest mass A₀ t ρ shared equally by its three nodes.

    Latex density is about 920–1000 kg/m³.
    """
    share = (density * thickness / 3.0) * mesh.reference_area
    flat = jnp.concatenate([share, share, share])
    nodes = jnp.concatenate([mesh.triangles[:, 0], mesh.triangles[:, 1], mesh.triangles[:, 2]])
    return jax.ops.segment_sum(flat, nodes, num_segments=mesh.num_nodes)
