"""The error bits: one flag per failure, distinct bits, a message each, usable inside jit."""

import jax
import jax.numpy as jnp
import numpy as np

from membrax import errors
from membrax.errors import ErrorCode
from membrax.membrane import candidates as membrane_candidates
from membrax.spheres import integrate


def test_every_error_is_its_own_bit_with_a_message():
    bits = [int(code) for code in ErrorCode if code]
    assert sorted(bits) == [2**k for k in range(len(bits))]  # 1, 2, 4, 8: no two share a bit
    for code in ErrorCode:
        assert len(errors.describe(code)) == (1 if code else 0)
    first, second = ErrorCode.NOT_FINITE, ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW
    assert errors.describe(np.int32(first | second)) == errors.describe(first) + errors.describe(second)
    assert errors.OVERFLOWS == ErrorCode.NEIGHBOR_OVERFLOW | ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW


def test_the_bits_combine_inside_jit_and_vmap_into_an_int32_mask():
    @jax.jit
    def mask(finite, overflow):
        error = jnp.zeros((), jnp.int32)
        error = error | jnp.where(finite, 0, ErrorCode.NOT_FINITE)
        return error | jnp.where(overflow, ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW, 0)

    out = jax.vmap(mask)(jnp.array([True, False, False]), jnp.array([False, False, True]))
    assert out.dtype == jnp.int32
    np.testing.assert_array_equal(out, [0, 2, 10])
    assert ErrorCode(int(out[2])) == ErrorCode.NOT_FINITE | ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW


def test_the_module_aliases_are_the_same_bits():
    assert integrate.ERROR_NEIGHBOR_OVERFLOW is ErrorCode.NEIGHBOR_OVERFLOW
    assert integrate.ERROR_NOT_FINITE is ErrorCode.NOT_FINITE
    assert integrate.ERROR_OUTSIDE_BOX is ErrorCode.OUTSIDE_BOX
    assert membrane_candidates.ERROR_MEMBRANE_CANDIDATE_OVERFLOW is ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW
    assert integrate.describe_errors is errors.describe


def test_not_finite_bit_flags_one_bad_entry_among_many_in_both_dtypes():
    # The steps' check sums each array: one NaN or infinity anywhere must survive the sum, +∞ and −∞
    # together included (∞ − ∞ = NaN), while finite entries up to 1e30 (a sum of 5e34 < 3.4e38) pass.
    rng = np.random.default_rng(0)
    check = jax.jit(jax.vmap(errors.not_finite_bit))
    for dtype in (jnp.float32, jnp.float64):
        with jax.enable_x64(dtype == jnp.float64):
            base = rng.uniform(-1.0, 1.0, (17115, 3))
            cases, expected = [], []
            for bad in ([], [np.nan], [np.inf], [-np.inf], [np.inf, -np.inf]):
                spoiled = base.copy()
                for value in bad:
                    spoiled[tuple(rng.integers(0, s) for s in base.shape)] = value
                cases.append(spoiled)
                expected.append(int(ErrorCode.NOT_FINITE) if bad else 0)
            cases.append(np.full(base.shape, 1e30))
            expected.append(0)
            positions = jnp.asarray(np.stack(cases), dtype)
            velocities = jnp.zeros_like(positions)
            np.testing.assert_array_equal(check(positions, velocities), expected)
            np.testing.assert_array_equal(check(velocities, positions), expected)  # either argument
