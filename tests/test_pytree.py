"""membrax.pytree: frozen dataclasses that are pytrees, through jit, vmap, grad and scan."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from membrax import pytree


@pytree.dataclass
class Spring:
    stiffness: jnp.ndarray
    extension: jnp.ndarray
    num_members: int = pytree.static_field()


def _energy(spring):
    """½ k x², summed: dE/dk = ½ x², dE/dx = k x (by hand)."""
    return jnp.sum(0.5 * spring.stiffness * spring.extension**2)


def test_leaves_are_the_array_fields_and_the_static_field_is_structure():
    spring = Spring(jnp.asarray([2.0, 3.0]), jnp.asarray([0.5, -1.0]), 2)
    leaves, tree = jax.tree_util.tree_flatten(spring)
    assert len(leaves) == 2
    assert jax.tree_util.tree_unflatten(tree, leaves).num_members == 2
    # set() copies; the instance itself is frozen
    longer = spring.set(extension=jnp.asarray([1.0, 1.0]))
    np.testing.assert_array_equal(np.asarray(spring.extension), [0.5, -1.0])
    np.testing.assert_array_equal(np.asarray(longer.extension), [1.0, 1.0])
    with pytest.raises(dataclasses.FrozenInstanceError):
        spring.extension = jnp.zeros(2)


def test_jit_grad_and_vmap_see_the_fields():
    spring = Spring(jnp.asarray([2.0, 3.0]), jnp.asarray([0.5, -1.0]), 2)
    # E = ½ (2 · 0.25 + 3 · 1) = 1.75
    assert float(jax.jit(_energy)(spring)) == pytest.approx(1.75, rel=1e-15)
    gradient = jax.grad(_energy)(spring)
    np.testing.assert_allclose(np.asarray(gradient.stiffness), [0.125, 0.5], rtol=1e-15)
    np.testing.assert_allclose(np.asarray(gradient.extension), [1.0, -3.0], rtol=1e-15)
    assert gradient.num_members == 2
    stacked = jax.tree_util.tree_map(
        lambda *xs: jnp.stack(xs), spring, spring.set(stiffness=2.0 * spring.stiffness)
    )
    np.testing.assert_allclose(np.asarray(jax.vmap(_energy)(stacked)), [1.75, 3.5], rtol=1e-15)


def test_a_static_field_change_recompiles_and_an_array_change_does_not():
    traces = []

    @jax.jit
    def scaled(spring):
        traces.append(spring.num_members)
        return spring.num_members * spring.extension

    spring = Spring(jnp.asarray([1.0]), jnp.asarray([2.0]), 1)
    scaled(spring)
    scaled(spring.set(extension=jnp.asarray([5.0])))
    assert traces == [1]
    np.testing.assert_array_equal(np.asarray(scaled(spring.set(num_members=3))), [6.0])
    assert traces == [1, 3]
