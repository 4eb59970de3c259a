"""The membrane's laws: stretching, bending and cell-pressure energies, their nodal forces, its masses.

Contract. Every function takes the current node positions (N, 3) and a :class:`MembraneMesh`
(:mod:`membrax.membrane.mesh`: topology, rest geometry and the kinematics the laws read — Green strains,
hinge angles, enclosed volume) with the material parameters, and returns an energy (J), nodal forces (N)
or node masses (kg). They are pure ``jnp`` functions, jittable and differentiable with respect to the
positions and the parameters; conservative nodal forces are ``-jax.grad`` of :func:`total_energy`
(:func:`nodal_forces`, on the CPU a compiled kernel held to that definition). SI units throughout: m, Pa,
N, J, kg.

Energies (reference: ``shared/reference/membrane-corrections.md`` §11):

- stretching: constant-strain triangles (CST) with an incompressible neo-Hookean or a St Venant–Kirchhoff
  law (:func:`stretching_energy`);
- bending: Discrete Shells (Grinspun et al. 2003) calibrated to the plate rigidity, k_b = D/6
  (:func:`bending_energy`);
- cell pressure: the load potential +p V, V the volume enclosed by the band closed with two flat caps
  (:func:`membrax.membrane.mesh.enclosed_volume`, :func:`pressure_energy`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from membrax import native
from membrax.defaults import LATEX_POISSON_RATIO, STRETCHING_MODELS
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
    "bending_rigidity",
    "bending_energy",
    "pressure_energy",
    "total_energy",
    "nodal_forces",
    "reference_nodal_forces",
    "lumped_mass",
]


def stretching_energy(
    position, mesh: MembraneMesh, modulus, thickness, model="neo_hookean", poisson_ratio=0.5
):
    """In-plane strain energy of the membrane with constant-strain triangles, J.

    Per triangle, with D_m the rest edge matrix in the triangle's plane and D_s = [x₂ − x₁, x₃ − x₁] (3 × 2):
    F = D_s D_m⁻¹, C = FᵀF, E = (C − I)/2 (reference §11; standard finite elements), and

    - ``"neo_hookean"`` (incompressible, plane stress, thickness t = t₀/√det C):
      W = t₀ A₀ (μ/2)(tr C + 1/det C − 3), μ = E_m/3 (so ν = ½);
    - ``"svk"`` (St Venant–Kirchhoff, plane stress): W = t₀ A₀ [μ tr(E²) + (λ*/2)(tr E)²],
      μ = E_m/(2(1+ν)), λ* = E_m ν/(1−ν²).

    Why neo-Hookean: latex is a rubber, near incompressible, and the membrane reaches tens of percent
    strain where bulging; the neo-Hookean law is the simplest finite-strain rubber law and reduces to
    E_m, ν = ½ at small strain. SVK is kept for small strains (below ~10 %) and other ν.

    Wrinkling: a membrane cannot carry compression. Here compression resistance comes from the bending
    energy (:func:`bending_energy`), which lets the mesh wrinkle at its own resolution; a tension-field
    (relaxed) energy is not implemented, so wrinkles finer than the mesh are not resolved.

    The neo-Hookean bracket is evaluated through E as (4(tr E)² + 8 tr E det E − 4 det E)/det C, an exact
    rewriting that avoids the cancellation of tr C + 1/det C − 3 at small strain (≈ 10 % error in float32
    at 10⁻³ strain otherwise).

    Args:
      position: (N, 3) current node positions, m.
      mesh: the membrane.
      modulus: E_m, Pa (scalar; traced, differentiable).
      thickness: t₀, m (scalar; traced, differentiable).
      model: ``"neo_hookean"`` or ``"svk"`` (static).
      poisson_ratio: ν of the SVK law (the neo-Hookean law is incompressible).

    Returns:
      Scalar energy, J.
    """
    return _stretching_energy_of(green_strain(position, mesh), mesh, modulus, thickness, model, poisson_ratio)


def _stretching_energy_of(strain, mesh: MembraneMesh, modulus, thickness, model, poisson_ratio):
    """:func:`stretching_energy` from the triangles' Green–Lagrange strain (E₁₁, E₂₂, E₁₂), (T,) each."""
    if model not in STRETCHING_MODELS:
        raise ValueError(f"model must be one of {STRETCHING_MODELS}, got {model!r}")
    e11, e22, e12 = strain
    trace = e11 + e22
    if model == "neo_hookean":
        determinant = e11 * e22 - e12 * e12
        det_c = 1.0 + 2.0 * trace + 4.0 * determinant
        bracket = (4.0 * trace * trace + 8.0 * trace * determinant - 4.0 * determinant) / det_c
        density = (modulus / 6.0) * bracket  # (μ/2)(...) with μ = E/3
    else:
        shear = modulus / (2.0 * (1.0 + poisson_ratio))
        lame = modulus * poisson_ratio / (1.0 - poisson_ratio * poisson_ratio)
        density = shear * (e11 * e11 + e22 * e22 + 2.0 * e12 * e12) + 0.5 * lame * trace * trace
    return thickness * jnp.sum(mesh.reference_area * density)


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
):
    """Stretching + bending + pressure potential of the membrane, J (see the three terms).

    ``bending_factor`` scales the bending energy: 1 is the plate's E t³/12(1 − ν²), 0 a pure membrane
    (a mesh with no bending stiffness, which may be what the paper's finite-difference mesh was).
    """
    # One pass over the triangles gives both the strain and the band's volume term.
    *strain, triple = triangle_invariants(gathered_corners(position, mesh), mesh.reference_inverse)
    return (
        _stretching_energy_of(strain, mesh, modulus, thickness, model, poisson_ratio)
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
):
    """Conservative nodal forces −∂(total energy)/∂x, (N, 3), N.

    On the CPU, in float32 or float64, the forces come from a compiled kernel (:mod:`membrax.native`,
    ``membrane_forces.cc``) that evaluates the same formulas in one pass over the triangles and hinges,
    and skips the hinges when ``bending_factor`` is 0. The JAX expression −∇(total energy) is used
    everywhere else and is the definition the tests hold the kernel to (agreement to round-off). Reverse
    mode (``jax.grad``, ``jax.vjp``) runs a compiled backward kernel on the CPU
    (``membrane_forces_backward``): the forces are −∇Φ, so their Jacobian is symmetric and Jᵀū is the
    directional derivative J ū, evaluated on dual numbers, with ū·∂F/∂(E_m, t_m, p, ν, f_b) from the same
    pass; it gives the JAX expression's derivatives to round-off (``tests/test_native.py``). When the
    mesh's rest geometry is differentiated, the JAX expression's own derivatives are used.
    """
    if model not in STRETCHING_MODELS:
        raise ValueError(f"model must be one of {STRETCHING_MODELS}, got {model!r}")
    position = jnp.asarray(position)
    args = (position, mesh, modulus, thickness, cell_pressure, poisson_ratio, bending_factor)
    if native.enabled_for(position.dtype):
        return _COMPILED_NODAL_FORCES[model](*args)
    return reference_nodal_forces(*args, model)


def reference_nodal_forces(
    position, mesh, modulus, thickness, cell_pressure, poisson_ratio, bending_factor, model
):
    """−∇(total energy) by ``jax.grad``: the definition of :func:`nodal_forces`."""
    return -jax.grad(total_energy)(
        position, mesh, modulus, thickness, cell_pressure, poisson_ratio, model, bending_factor
    )


_COMPILED_NODAL_FORCES = {
    model: native.with_reference(
        functools.partial(_kernels.nodal_forces_kernel, model=model),
        functools.partial(reference_nodal_forces, model=model),
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
