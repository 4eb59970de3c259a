"""The stage protocol of a triaxial test, shared by the rigid-wall and the membrane cell.

Contract. :class:`StagedTest` runs the two stages of the test with the chunk driver
(:class:`membrax.driver.ChunkRunner`) and returns the state and the records:

1. :meth:`StagedTest.consolidate`: isotropic consolidation, the servos on, until the cell's own stop test
   holds (:meth:`is_consolidated`: an unbalanced-force ratio below the tolerance, stresses at σc, ...);
2. :meth:`StagedTest.shear`: strain-controlled drained shearing from an inertial number (ramped from
   rest where the cell says so), recorded every ``record_every_fine`` steps up to ``fine_until_strain``
   and every ``record_every_coarse`` steps after (:func:`membrax.driver.two_rate_plan`).

A cell (:class:`membrax.triaxial.rigid.RigidWallTest`, :class:`membrax.triaxial.membrane_cell.MembraneTest`)
says what its platens and walls do at each stage.
"""

from __future__ import annotations

import numpy as np

from membrax.config import default_consolidation_tolerance
from membrax.driver import run_phases, two_rate_plan
from membrax.validation import check_range

__all__ = ["StagedTest"]


class StagedTest:
    """The two stages of a triaxial test, shared by the rigid-wall and the membrane test.

    A subclass (a dataclass with ``initial_state``, ``params`` and ``runner``, a :class:`ChunkRunner`)
    says what its cell does at each stage:

    - ``cell``: ``"rigid"`` or ``"membrane"``, the default consolidation tolerance's row
      (:func:`membrax.config.default_consolidation_tolerance`);
    - ``default_ramp_strain``: the shearing's default start-up ramp (axial strain at full speed);
    - ``start_consolidation(state)``: the servos on, at rest;
    - ``is_consolidated(records, tolerance, **criteria)``: the stop test on a chunk's records;
    - ``shear_rate(inertial_number)``: the axial strain rate ε̇ of an inertial number, 1/s;
    - ``start_shear(state, inertial_number, ramp_strain, **loading)``: the strain-controlled platens;
    - ``dt``: the time step, s.
    """

    cell = "rigid"
    default_ramp_strain = 0.0

    def consolidate(
        self,
        state=None,
        tolerance: float | None = None,
        max_steps: int = 200_000,
        chunk_steps: int = 2000,
        record_every: int = 100,
        on_chunk=None,
        **criteria,
    ):
        """Stage 1: isotropic consolidation until ``is_consolidated`` holds (or ``max_steps``).

        Args:
          state: starting state (default: the as-built specimen).
          tolerance: unbalanced-force ratio to reach; default
            :func:`membrax.config.default_consolidation_tolerance` for the cell and the state's precision.
          max_steps: give up after this many steps (the records show how far it got).
          chunk_steps: steps per compiled chunk.
          record_every: steps between records.
          on_chunk: progress callback ``on_chunk(state, records)``.
          **criteria: the cell's further stop criteria (``stress_tolerance``, ...; ``is_consolidated``).

        Returns:
          (state, records); ``records.step`` counts from the start of the test.
        """
        state = self.initial_state if state is None else state
        if tolerance is None:
            dtype = self.runner.dem_of(state).position.dtype
            tolerance = default_consolidation_tolerance(self.cell, dtype == np.float64)
        state = self.start_consolidation(state)

        def stop(_, records):
            return self.is_consolidated(records, tolerance, **criteria)

        return self.runner.run(
            state, self.params, max_steps, chunk_steps, record_every, stop_fn=stop, on_chunk=on_chunk
        )

    def shear_plan(
        self,
        target_axial_strain: float = 0.10,
        inertial_number: float = 1e-3,
        fine_until_strain: float = 0.01,
        ramp_strain: float | None = None,
    ) -> tuple[int, int]:
        """Steps of the two recording phases of stage 2: (fine, coarse).

        Axial strain counts from the start of shearing: at full speed the platens close ε̇ H Δt per step, so
        ε_a reaches ``fine_until_strain`` after (ε + ε_ramp)/(ε̇ Δt) steps (the ramp delays it by ε_ramp/ε̇,
        :func:`membrax.driver.two_rate_plan`) and the target after the rest.
        """
        check_range(
            "target_axial_strain", target_axial_strain, lower=0.0, upper=1.0, lower_open=True, upper_open=True
        )
        ramp = self.default_ramp_strain if ramp_strain is None else ramp_strain
        steps_per_strain = 1.0 / (self.shear_rate(inertial_number) * self.dt)
        return two_rate_plan(steps_per_strain, target_axial_strain, fine_until_strain, ramp)

    def shear(
        self,
        state,
        target_axial_strain: float = 0.10,
        inertial_number: float = 1e-3,
        record_every_fine: int = 25,
        fine_until_strain: float = 0.01,
        record_every_coarse: int = 250,
        chunk_steps: int = 5000,
        on_chunk=None,
        ramp_strain: float | None = None,
        **loading,
    ):
        """Stage 2: strain-controlled drained shearing, recorded at two rates (module docstring).

        Args:
          state: the consolidated state.
          target_axial_strain: axial strain to reach, counted from the start of shearing.
          inertial_number: I, setting the strain rate.
          record_every_fine: steps between records below ``fine_until_strain``.
          fine_until_strain: the end of the fine recording.
          record_every_coarse: steps between records after it.
          chunk_steps: steps per compiled chunk.
          on_chunk: progress callback ``on_chunk(state, records)``.
          ramp_strain: axial strain at which the platens reach full speed (default the cell's).
          **loading: the cell's further loading options (``symmetric`` for the membrane test).

        Returns:
          (state, records) with the records of both recording rates joined.
        """
        ramp = self.default_ramp_strain if ramp_strain is None else ramp_strain
        fine, coarse = self.shear_plan(target_axial_strain, inertial_number, fine_until_strain, ramp)
        state = self.start_shear(state, inertial_number, ramp, **loading)
        phases = [(fine, record_every_fine), (coarse, record_every_coarse)]
        return run_phases(self.runner, state, self.params, phases, chunk_steps, on_chunk)
