"""Gradients through rollouts (membrax.gradients) and the smooth mode; the inverse problem: notebook 04

Smoothness conditions of the gradient checks. Reverse mode through a rollout is the derivative of the map
θ → final state where that map is smooth. In the smooth mode (``viscous_damping = true``) each step is
continuous and piecewise smooth; its kinks are contact onsets and Coulomb caps. Central differences with
h = 1e-6 θ match the reverse-mode derivative where no contact opens, closes or starts to slide between θ − h
and θ + h at any step; at h = 1e-4 θ some do during the consolidation transient (measured: up to 15 %
apart on internal σ1 w.r.t. σc after 1,000 steps), at 1e-6 θ they agree within 4e-6. The paper's damping
(Cundall local, sign(v)) makes the step discontinuous instead, and there is no derivative to check
(membrax.gradients).
"""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SMALL_MEMBRANE_TEST

from membrax import gradients, sensitivities
from membrax.assemble import build_test
from membrax.spheres.contact import tangential_spring_update
from membrax.spheres.integrate import DampingParams
from membrax.spheres.particles import particle_mass
from membrax.spheres.walls import platen_separation

SMOOTH = dataclasses.replace(SMALL_MEMBRANE_TEST, viscous_damping=True)


def test_viscous_damping_removes_what_local_damping_does_per_cycle_and_is_off_by_default():
    # off: the paper's Cundall local damping α = 0.3 and no viscous term, as before the option existed
    paper = build_test(dataclasses.replace(SMOOTH, viscous_damping=False)).params.dem.damping
    assert float(paper.local_coefficient) == pytest.approx(0.3) and float(paper.viscous_rate) == 0.0
    assert paper.frame == "affine"  # relative to the platens' affine field (membrax.defaults.DAMPING_FRAME)
    # on: equal energy loss per cycle of a contact oscillator (k_n, m): 2αkA² = 4πζ·½kA², γ = 2ζω = 2αω/π
    smooth = build_test(SMOOTH).params.dem.damping
    mass = float(particle_mass(SMOOTH.particle_radius, SMOOTH.particle_density_kg_m3))
    omega = math.sqrt(SMOOTH.particle_stiffness_n_m / mass)
    assert float(smooth.local_coefficient) == 0.0 and smooth.frame == "affine"
    assert float(smooth.viscous_rate) == pytest.approx(2 * 0.3 * omega / math.pi, rel=1e-6)
    # the derivation, checked on one oscillator (k, m) integrated over one period from x = A at rest, for a
    # light α = 0.01 where the per-cycle losses are linear in the damping: the two lose the same energy
    k, m, alpha = 1e7, mass, 0.01
    gamma = float(DampingParams.equivalent_viscous(k, m, alpha).viscous_rate)
    period = 2 * math.pi * math.sqrt(m / k)
    dt = period / 20000

    def energy_lost(force):
        x, v = 1e-4, 0.0
        for _ in range(20000):
            v += dt * force(x, v) / m
            x += dt * v
        return 1.0 - (0.5 * k * x * x + 0.5 * m * v * v) / (0.5 * k * 1e-8)

    local = energy_lost(lambda x, v: -k * x - alpha * abs(k * x) * np.sign(v))
    viscous = energy_lost(lambda x, v: -k * x - gamma * m * v)
    assert viscous == pytest.approx(local, rel=0.02)
    assert local == pytest.approx(4 * alpha, rel=0.02)  # 2αkA² of ½kA²
    assert DampingParams.equivalent_viscous(1e7, mass).viscous_rate == pytest.approx(smooth.viscous_rate)


def test_spring_rotation_is_unchanged_for_physical_springs_and_bounded_for_round_off_ones():
    with jax.enable_x64(True):
        normal = jnp.array([0.0, 0.0, 1.0])
        zero = jnp.zeros(3)

        def update(spring):
            return tangential_spring_update(spring, normal, zero, 1e-5, 5e6, 10.0, 100.0, True)

        # a spring tilted 1e-3 rad out of the tangent plane comes back into it with its length kept:
        # |s| Π_t(s)/|Π_t(s)| (the law before the cap, by hand)
        tilted = jnp.array([0.3, 0.4, 0.5 * 1e-3])
        expected = 0.5 * np.array([0.6, 0.8, 0.0]) * np.linalg.norm(tilted) / 0.5
        np.testing.assert_allclose(update(tilted), expected, rtol=1e-14)
        # a round-off spring along the normal (1e-18 N, measured in FCC contacts): the uncapped rescaling
        # |s|/|Π_t(s)| had a derivative of ~1e16; capped at 2 the Jacobian stays O(1) and equals
        # central differences
        round_off = jnp.array([1e-24, 0.0, 1e-18])
        jacobian = np.asarray(jax.jacrev(update)(round_off))
        assert np.max(np.abs(jacobian)) <= 2.0 + 1e-12
        assert np.max(np.abs(update(round_off))) <= 2.0 * 1e-24 + 1e-30
        spring = jnp.array([0.3, -0.2, 0.25])  # 44° out of the plane: still uncapped, a smooth region
        jacobian = np.asarray(jax.jacrev(update)(spring))
        for k in range(3):
            step = np.zeros(3)
            step[k] = 1e-6
            difference = (np.asarray(update(spring + step)) - np.asarray(update(spring - step))) / 2e-6
            np.testing.assert_allclose(jacobian[:, k], difference, rtol=1e-6, atol=1e-9)


def test_rollouts_name_the_bad_count_before_building_anything():
    wrt = ("membrane_modulus_kpa",)
    for counts, named in (
        ({"steps": 0}, "steps = 0"),
        ({"window": 0}, "window = 0"),
        ({"unroll": 0}, "unroll = 0"),
    ):
        arguments = {"steps": 10, **counts}
        with pytest.raises(ValueError, match=named):
            gradients.consolidation_rollout(SMOOTH, wrt, **arguments)
    with pytest.raises(ValueError, match="unroll = -1"):
        gradients.shearing_rollout(SMOOTH, wrt, shear_steps=10, consolidation_steps=10, unroll=-1)


def test_windows_checkpoint_each_step_on_a_cpus_jax_path_alone_and_differentiate_alike(monkeypatch):
    # a window of 4 steps x → a x: y = a⁴ x, dy/da = 4 a³ x, whichever way the window is checkpointed. Each
    # step is checkpointed too where XLA's CPU derivative of the JAX code would keep ~70 MB per step
    # (no kernels: MEMBRAX_NATIVE=0), not with the kernels, nor on a GPU (its compiler keeps ~3 MB,
    # docs/gradients.md)
    from membrax import native

    def checkpoints_and_gradient(rematerialize_steps=None):
        run = gradients.checkpoint_window(lambda x, a: a * x, 4, jnp.float64, rematerialize_steps)
        objective = lambda a: run(jnp.float64(3.0), a)  # noqa: E731
        jaxpr = str(jax.make_jaxpr(jax.grad(objective))(jnp.float64(1.5)))
        return jaxpr.count("remat"), float(jax.grad(objective)(jnp.float64(1.5)))

    window_only, gradient = checkpoints_and_gradient(False)
    each_step, gradient_each = checkpoints_and_gradient(True)
    assert each_step > window_only
    for value in (gradient, gradient_each):
        assert value == pytest.approx(4 * 1.5**3 * 3.0, rel=1e-14)
    cases = (
        ("kernels", "1", "cpu", window_only),
        ("JAX code", "0", "cpu", each_step),
        ("GPU", "1", "gpu", window_only),
    )
    for name, kernels, backend, expected in cases:
        with monkeypatch.context() as patch:
            patch.setenv("MEMBRAX_NATIVE", kernels)
            patch.setattr(jax, "default_backend", lambda backend=backend: backend)
            native.available.cache_clear()
            try:
                if name == "kernels" and not native.runs_kernels(jnp.float64):
                    continue  # no compiler here: the kernels' case cannot be traced
                assert checkpoints_and_gradient() == (expected, pytest.approx(gradient, rel=1e-14)), name
            finally:
                native.available.cache_clear()


@pytest.mark.slow
def test_checkpointed_gradients_through_consolidation_and_shearing_match_central_differences_under_vmap():
    # two Table 1-like members in one compiled call (vmap): 10 kPa in 5 mm, 40 kPa in 2.5 mm; 1,000 steps of
    # consolidation, then 1,000 of shearing at I = 0.01 with a ramp to 0.1 % strain (ε̇ Δt = 8.8e-6 per step
    # at 10 kPa: ε_a ≈ 0.8 %, twice that at 40 kPa), the whole path differentiated. Notebook 04's smoke run
    # (CI) takes this rollout's Jacobian too and leaves its check against central differences to this test.
    shearing = {"inertial_number": 0.01, "shear_ramp_strain": 0.001}
    configs = [
        dataclasses.replace(SMOOTH, **shearing),
        dataclasses.replace(SMOOTH, cell_pressure_kpa=40.0, membrane_thickness_mm=2.5, **shearing),
    ]
    wrt = ("cell_pressure_kpa", "membrane_modulus_kpa", "membrane_friction_angle_deg")
    with jax.enable_x64(True):
        rollout = gradients.shearing_rollout(configs, wrt, shear_steps=1000, consolidation_steps=1000)
        values, jacobian = gradients.rollout_jacobian(rollout)
        differences = gradients.rollout_differences(rollout, relative_step=1e-6)
        final, (start_height, _), _, _ = jax.vmap(rollout.member_final)(
            jnp.asarray(rollout.theta0), *rollout.real_members(), rollout.geometry
        )
    # the platens close at ε̇ H₀ after a linear ramp of 2 ε_r/ε̇: ε_a = ε̇ t − ε_r, ε̇ = I √(σc/ρ)/d
    rate = np.asarray([test.shear_rate(0.01) for test in rollout.batch.tests])
    expected = rate * 1000 * rollout.batch.tests[0].dt - 0.001  # 7.79e-3, 1.66e-2
    strain = 1.0 - np.asarray(jax.vmap(platen_separation)(final.dem.walls)[:, 0]) / np.asarray(start_height)
    np.testing.assert_allclose(strain, expected, rtol=1e-3)  # measured 6e-4: the ramp's discrete steps
    assert values.shape == (2, len(sensitivities.OUTPUTS)) and jacobian.shape == (2, 6, 3)
    # the external radial stress is the cell's: σ_ext,r = σc (kPa → Pa: 1e3), exactly, shearing or not
    np.testing.assert_allclose(values[:, 1], [1e4, 4e4], rtol=1e-9)
    np.testing.assert_allclose(jacobian[:, 1, 0], 1e3, rtol=1e-9)
    # sheared: the deviator σ1 − σ3 of the internal stresses is well above the cell pressure
    internal = [sensitivities.OUTPUTS.index(n) for n in ("internal_axial_stress", "internal_radial_stress")]
    assert np.all(values[:, internal[0]] - values[:, internal[1]] > np.array([1e4, 4e4]))
    for b in range(2):
        for row in [*internal, sensitivities.OUTPUTS.index("additional_axial_stress")]:
            np.testing.assert_allclose(jacobian[b, row], differences[b, row], rtol=1e-3)
    # membrane friction acts along the path (the equilibrium's implicit derivative is 0): here it is not
    assert np.all(np.abs(jacobian[:, internal, 2]) > 1.0)  # Pa per degree
