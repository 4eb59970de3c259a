"""membrax.fusion.materialize: the identity, with its derivatives, that XLA-CPU keeps as a stored array."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from membrax.fusion import materialize


def _energy(x):
    # A nonlinear scalar whose gradient is known in closed form: d/dx Σ sin²(2x) = 2 sin(4x).
    return jnp.sum(jnp.sin(2.0 * x) ** 2)


def _energy_through(x):
    return jnp.sum(jnp.sin(materialize(2.0 * x)) ** 2)


def test_values_pass_unchanged_bit_for_bit():
    values = jnp.asarray([0.3, -1.5, jnp.nan, jnp.inf, 0.0])
    counts = jnp.asarray([3, -7, 0])
    mask = jnp.asarray([True, False])
    out = jax.jit(lambda *a: materialize(*a))(values, counts, mask)
    for given, returned in zip((values, counts, mask), out, strict=True):
        assert returned.dtype == given.dtype
        np.testing.assert_array_equal(np.asarray(returned), np.asarray(given))  # NaN == NaN here
    single = materialize(values)
    assert isinstance(single, jax.Array) and single.shape == values.shape


def test_outside_a_trace_the_arrays_come_back_as_they_are():
    # Eagerly there is nothing to fuse: the same array objects, not a conditional's copies.
    values, counts = jnp.asarray([0.3, -1.5, jnp.nan]), jnp.asarray([3, -7])
    assert materialize(values) is values
    returned = materialize(values, counts)
    assert returned[0] is values and returned[1] is counts
    # Traced, the conditional is there: the stored array is another one with the same bits.
    assert "cond" in str(jax.make_jaxpr(materialize)(values))


def test_gradient_and_tangent_are_the_identitys():
    x = jnp.linspace(-1.0, 1.0, 11)
    closed_form = 2.0 * jnp.sin(4.0 * x)
    np.testing.assert_allclose(jax.grad(_energy_through)(x), closed_form, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(jax.jit(jax.grad(_energy_through))(x), closed_form, rtol=1e-13, atol=1e-14)
    direction = jnp.exp(x)  # not orthogonal to the odd gradient
    _, tangent = jax.jvp(_energy_through, (x,), (direction,))
    np.testing.assert_allclose(tangent, jnp.dot(closed_form, direction), rtol=1e-13)
    # Second derivative, forward over reverse: d²/dx² sin²(2x) = 8 cos(4x) on the diagonal.
    hessian = jax.jacfwd(jax.grad(_energy_through))(x)
    np.testing.assert_allclose(jnp.diag(hessian), 8.0 * jnp.cos(4.0 * x), rtol=1e-12, atol=1e-12)


def test_vmap_matches_a_loop_and_keeps_one_conditional():
    batch = jnp.stack([jnp.linspace(0.0, 1.0, 7), jnp.linspace(-2.0, 0.5, 7)])
    batched = jax.jit(jax.vmap(jax.grad(_energy_through)))(batch)
    for row, member in zip(batched, batch, strict=True):
        np.testing.assert_allclose(row, 2.0 * jnp.sin(4.0 * member), rtol=1e-13, atol=1e-14)
    # The contract on XLA-CPU: the stored array survives compilation as a conditional, also under vmap
    # (a batched predicate would have become a select and been fused away).
    if jax.default_backend() == "cpu":
        for compiled in (
            jax.jit(_energy_through).lower(batch[0]).compile(),
            jax.jit(jax.vmap(_energy_through)).lower(batch).compile(),
        ):
            assert "conditional(" in compiled.as_text()
        assert "conditional(" not in jax.jit(_energy).lower(batch[0]).compile().as_text()


def test_no_arrays_is_an_error():
    with pytest.raises(ValueError, match="at least one array"):
        materialize()
    empty = jnp.zeros((0, 3))
    assert materialize(empty).shape == (0, 3)
