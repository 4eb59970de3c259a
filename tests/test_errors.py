"""The error bits: one flag per failure, distinct bits, a message each, usable inside jit."""

import jax
import jax.numpy as jnp
import numpy as np

from membrax import errors
from membrax.errors import ErrorCode
from membrax.membrane import contact as membrane_contact
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
    assert membrane_contact.ERROR_MEMBRANE_CANDIDATE_OVERFLOW is ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW
    assert integrate.describe_errors is errors.describe
