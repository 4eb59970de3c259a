"""Random packings made in the periodic cell: a gas compressed isotropically to σc.

Contract. :func:`compact_periodic` returns ``(test, state, records)``: the periodic cell
(:func:`membrax.triaxial.periodic.periodic_test`) of the compaction, its state at rest at σc, and the records
of its stages. The packing is made as the mould's are (:mod:`membrax.spheres.compaction`) without walls: a
random gas (:func:`membrax.spheres.periodic.random_gas`) compressed by the cell's stress servo with a
compaction friction coefficient in place of the contact law's (0.5 gives a loose packing; 0 a dense one,
compressed to 10 σc and unloaded), so the same spheres give the same states in both.

Given a ``checkpoint_path``, its stages (the overload compression, the unloading) write their state and
records to that file as they go (:class:`membrax.triaxial.stage_checkpoint.StageCheckpoint`), and a
call with the same arguments resumes from it to the same state and records, to the bit, as an
uninterrupted one; the file is deleted when the compaction is complete.
"""

from __future__ import annotations

import dataclasses as pydataclasses
import hashlib

import jax.numpy as jnp
import numpy as np

from membrax.driver import concatenate_records
from membrax.spheres.contact import ContactParams
from membrax.spheres.periodic import random_gas
from membrax.triaxial.periodic import periodic_test
from membrax.triaxial.stage_checkpoint import StageCheckpoint

__all__ = ["compact_periodic"]


def compact_periodic(
    diameters,
    cell_pressure: float,
    friction_coefficient: float = 0.0,
    seed: int = 0,
    gas_solid_fraction: float = 0.25,
    tolerance: float = 1e-4,
    max_steps: int = 400_000,
    overload: float | None = None,
    dtype=None,
    checkpoint_path=None,
    checkpoint_every_chunks: int | None = None,
    checkpoint_every_seconds: float | None = 120.0,
    report=None,
    **options,
):
    """A random packing compressed isotropically to σc in a periodic cell.

    The gas (:func:`membrax.spheres.periodic.random_gas`) is compressed by the box servo (every axis to σc,
    at most ``options["max_inertial_number"]``) with the compaction friction μ_c in place of the contact law's
    friction. μ_c = 0.5 gives a loose packing at rest (150 spheres, d ± 20 %, 100 kPa: φ ≈ 0.56 and the
    unbalanced-force ratio below 1e-3 within ~30,000 steps, ``tests/test_periodic.py``).

    A frictionless packing (μ_c = 0) below jamming carries σc only while it is being compressed, so a
    servo held at σc keeps the box moving and the packing creeps up slowly (measured: 300 spheres,
    d ± 10 %, 100 kPa, I_max = 0.01: φ = 0.628 after 30,000 steps, the unbalanced-force ratio still ~0.1;
    held at that box the stress fell from 93 kPa to 1.3 kPa in 20,000 steps). So it is first compressed to
    ``overload`` × σc, well into the jammed range where stress is carried statically, then unloaded to σc:
    a jammed frictionless packing unloads reversibly, losing overlap but not contacts. Measured (same 300
    spheres, float32, overload 10, 36,000 steps in all): φ = 0.6348, z = 6.11, z* = 6.17 (rattlers 1.0 %),
    unbalanced-force ratio 8e-4, and at a fixed box the stress stayed within 100.00–100.02 kPa over 10,000
    steps (jammed). Agnolin & Roux (2007, Phys. Rev. E 76, 061302) find φ ≈ 0.639 and z* → 6 in the rigid
    limit for random close packing (here κ = k_n/(σc d) = 4000, so z* sits a little above 6; a first stage
    run with its rate limit at 10 σc instead gave φ = 0.6379, z* = 6.20: the compression rate moves φ by
    a few thousandths).

    Returns (test, state, records): ``test`` the compaction's cell, ``state`` where it stopped
    (unbalanced-force ratio below ``tolerance`` and stresses within 1 % of σc, or the step budgets), the
    records of both stages joined.

    Args:
      diameters: (N,) diameters, m.
      cell_pressure: σc, Pa.
      friction_coefficient: μ_c during the compaction.
      seed: the gas's seed.
      gas_solid_fraction: φ of the gas.
      tolerance: the unbalanced-force ratio at which the packing counts as at rest.
      max_steps: each stage's step budget.
      overload: the first stage's target as a multiple of σc (default 10 without friction, else 1: no
        second stage).
      dtype: the simulation's float dtype (default JAX's).
      checkpoint_path: a file to which the stages write their progress, and from which a call with the
        same arguments resumes (None: no checkpoints); deleted once the compaction is complete. A
        checkpoint of other diameters, σc, μ_c, seed, gas φ, tolerance, budget, overload or precision is
        refused (ValueError naming it); the contact law and the other ``options`` are not checked.
      checkpoint_every_chunks: write a checkpoint after this many chunks of 2,000 steps (None: by time).
      checkpoint_every_seconds: write one once this many seconds have passed since the last (None: by
        chunks); with both None, at the end of the first stage only.
      report: ``report(line)`` called with a line (stage, step) after each checkpoint, e.g. ``print``.
      **options: further arguments of :func:`membrax.triaxial.periodic.periodic_test` (contact law's
        stiffnesses, damping, ...).
    """
    fraction, length, sorted_diameters = random_gas(diameters, gas_solid_fraction, seed)
    contact_params = options.pop("contact_params", None) or ContactParams.paper()
    contact_params = contact_params.set(friction_coefficient=jnp.asarray(friction_coefficient))
    fraction = jnp.asarray(fraction, dtype) if dtype is not None else jnp.asarray(fraction)
    test = periodic_test(
        fraction, length, 0.5 * sorted_diameters, cell_pressure, contact_params=contact_params, **options
    )
    if overload is None:
        overload = 10.0 if friction_coefficient == 0.0 else 1.0
    loaded = pydataclasses.replace(test, cell_pressure=overload * cell_pressure)
    if checkpoint_path is None:
        state, records = loaded.consolidate(tolerance=tolerance, max_steps=max_steps)
        if overload != 1.0:
            state, unloading = test.consolidate(state, tolerance=tolerance, max_steps=max_steps)
            records = concatenate_records([records, unloading])
        return test, state, records
    stages = ("overload", "unloading") if overload != 1.0 else ("overload",)
    signature = {
        "num_spheres": int(np.size(diameters)),
        "diameters_sha256": hashlib.sha256(np.asarray(diameters, np.float64).tobytes()).hexdigest(),
        "cell_pressure": float(cell_pressure),
        "friction_coefficient": float(friction_coefficient),
        "seed": int(seed),
        "gas_solid_fraction": float(gas_solid_fraction),
        "tolerance": float(tolerance),
        "max_steps": int(max_steps),
        "overload": float(overload),
        "dtype": str(test.initial_state.length.dtype),
    }
    checkpoint = StageCheckpoint(
        checkpoint_path,
        test,
        stages,
        signature,
        every_chunks=checkpoint_every_chunks,
        every_seconds=checkpoint_every_seconds,
        report=report,
    )
    state, records = checkpoint.consolidate("overload", loaded, tolerance=tolerance, max_steps=max_steps)
    if overload != 1.0:
        state, unloading = checkpoint.consolidate("unloading", test, state, tolerance, max_steps)
        records = concatenate_records([records, unloading])
    checkpoint.remove()
    return test, state, records
