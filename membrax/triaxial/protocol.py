"""The stage protocol of a triaxial test, shared by the rigid-wall and the membrane cell.

Contract. :class:`StagedTest` runs the two stages of the test with the chunk driver
(:class:`membrax.driver.ChunkRunner`) and returns the state and the records:

1. :meth:`StagedTest.consolidate`: isotropic consolidation, the servos on, until the cell's own stop test
   holds (:meth:`is_consolidated`: an unbalanced-force ratio below the tolerance, stresses at σc, ...);
2. :meth:`StagedTest.shear`: strain-controlled drained shearing from an inertial number (ramped from
   rest where the cell says so), recorded every ``record_every_fine`` steps up to ``fine_until_strain``
   and every ``record_every_coarse`` steps after (:func:`membrax.driver.two_rate_plan`), optionally at
   another inertial number after ``fine_until_strain`` (:meth:`StagedTest.change_shear_rate`).

A cell (:class:`membrax.triaxial.rigid.RigidWallTest`, :class:`membrax.triaxial.membrane_cell.MembraneTest`)
says what its platens and walls do at each stage.

The stage sequence is written once, here: :data:`PHASES` in order, what changes at the start of each
(:meth:`StagedTest.start_phase`) and each phase's steps and record interval (:meth:`StagedTest.phase_plan`)
under a :class:`Loading`. :meth:`StagedTest.consolidate` and :meth:`StagedTest.shear` run it on one
state; :func:`membrax.runner.run_group` runs it on a batch of members (a single test from a configuration
is a batch of one; :func:`membrax.executor.build_batch` starts them at the first phase), with checkpoints,
resume and progress.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from membrax.defaults import default_consolidation_tolerance
from membrax.driver import concatenate_records, run_phases, two_rate_plan
from membrax.spheres.walls import change_speed
from membrax.validation import check_range

__all__ = ["CONSOLIDATION_RECORD_EVERY", "PHASES", "Loading", "StagedTest"]

#: The phases of a test, in order: consolidation (until the cell's stop test holds), then shearing
#: recorded every ``record_every_fine`` steps to ``fine_until_strain`` and every ``record_every_coarse``
#: steps after, to the target strain.
PHASES = ("consolidation", "shear_fine", "shear_coarse")
#: Steps between consolidation records.
CONSOLIDATION_RECORD_EVERY = 100


@dataclasses.dataclass(frozen=True)
class Loading:
    """The loading programme of a test: what the phases of :data:`PHASES` need to plan their steps.

    No defaults of its own: a configuration gives them (:func:`membrax.assemble.loading`), or a stage's
    arguments (:meth:`StagedTest.shear`).

    Attributes:
      consolidation_max_steps: consolidation gives up after this many steps.
      target_axial_strain: axial strain at which shearing stops, counted from its start.
      inertial_number: I, setting the shear strain rate (the cell's :meth:`StagedTest.shear_rate`).
      fine_until_strain: the end of the fine recording.
      ramp_strain: axial strain at which the platens reach full speed (None: the cell's default).
      record_every_fine: steps between records below ``fine_until_strain``.
      record_every_coarse: steps between records after it.
      consolidation_record_every: steps between consolidation records.
      coarse_inertial_number: I of the coarse phase, reached by a linear change of speed over
        ``ramp_strain`` after ``fine_until_strain`` (:meth:`StagedTest.change_shear_rate`); None: the
        fine phase's ``inertial_number`` throughout.
      symmetric: both platens move in shearing (True) or the top one alone (False); None: the cell's
        default (``start_shear``'s).
    """

    consolidation_max_steps: int
    target_axial_strain: float
    inertial_number: float
    fine_until_strain: float
    ramp_strain: float | None
    record_every_fine: int
    record_every_coarse: int
    consolidation_record_every: int = CONSOLIDATION_RECORD_EVERY
    coarse_inertial_number: float | None = None
    symmetric: bool | None = None


class StagedTest:
    """The two stages of a triaxial test, shared by the rigid-wall and the membrane test.

    A subclass (a dataclass with ``initial_state``, ``params`` and ``runner``, a :class:`ChunkRunner`)
    says what its cell does at each stage:

    - ``cell``: ``"rigid"`` or ``"membrane"``, the default consolidation tolerance's row
      (:func:`membrax.defaults.default_consolidation_tolerance`);
    - ``default_ramp_strain``: the shearing's default start-up ramp (axial strain at full speed);
    - ``start_consolidation(state)``: the servos on, at rest;
    - ``is_consolidated(records, tolerance, **criteria)``: the stop test on a chunk's records;
    - ``shear_rate(inertial_number)``: the axial strain rate ε̇ of an inertial number, 1/s;
    - ``start_shear(state, inertial_number, ramp_strain, symmetric=...)``: the strain-controlled platens;
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
        record_every: int = CONSOLIDATION_RECORD_EVERY,
        on_chunk=None,
        **criteria,
    ):
        """Stage 1: isotropic consolidation until ``is_consolidated`` holds (or ``max_steps``).

        Args:
          state: starting state (default: the as-built specimen).
          tolerance: unbalanced-force ratio to reach; default
            :func:`membrax.defaults.default_consolidation_tolerance` for the cell and the state's precision.
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
        state = self.start_phase("consolidation", state)

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
        coarse_inertial_number: float | None = None,
    ) -> tuple[int, int]:
        """Steps of the two recording phases of stage 2: (fine, coarse).

        The fine phase runs at the strain rate of ``inertial_number`` to ``fine_until_strain``, the coarse
        phase at that of ``coarse_inertial_number`` (None: ``inertial_number``'s) to the target; how many
        steps a strain takes is the cell's (:meth:`steps_at_rates`).
        """
        check_range(
            "target_axial_strain", target_axial_strain, lower=0.0, upper=1.0, lower_open=True, upper_open=True
        )
        fine_rate = self.shear_rate(inertial_number)
        coarse_rate = None if coarse_inertial_number is None else self.shear_rate(coarse_inertial_number)
        return self.steps_at_rates(
            target_axial_strain, fine_until_strain, ramp_strain, fine_rate, coarse_rate
        )

    def steps_at_rates(
        self, target_axial_strain, fine_until_strain, ramp_strain, fine_rate, coarse_rate
    ) -> tuple[int, int]:
        """:meth:`shear_plan`'s (fine, coarse) steps at the strain rates ``fine_rate`` and ``coarse_rate``.

        Axial strain counts from the start of shearing: at full speed the platens close ε̇ H Δt per step, so
        ε_a reaches ``fine_until_strain`` after (ε + ε_ramp)/(ε̇ Δt) steps (the ramp delays it by ε_ramp/ε̇,
        :func:`membrax.driver.two_rate_plan`) and the target after the rest, at ``coarse_rate`` (None:
        ``fine_rate``) once the speed has changed over ε_ramp (``ramp_strain``, None: the cell's default).
        """
        ramp = self.default_ramp_strain if ramp_strain is None else ramp_strain
        steps_per_strain = 1.0 / (fine_rate * self.dt)
        coarse_steps_per_strain = None if coarse_rate is None else 1.0 / (coarse_rate * self.dt)
        return two_rate_plan(
            steps_per_strain, target_axial_strain, fine_until_strain, ramp, coarse_steps_per_strain
        )

    def change_shear_rate(
        self, state, inertial_number: float, coarse_inertial_number: float, ramp_strain: float | None = None
    ):
        """Switch a shearing ``state`` to the strain rate of ``coarse_inertial_number``.

        The constant-velocity platens change speed from ``inertial_number``'s linearly over the axial strain
        ``ramp_strain`` (default the cell's; 0: a step change), :func:`membrax.spheres.walls.change_speed`.
        """
        ramp = self.default_ramp_strain if ramp_strain is None else ramp_strain
        rate = self.shear_rate(inertial_number)
        factor = self.shear_rate(coarse_inertial_number) / rate
        dem = self.runner.dem_of(state)
        return self.runner.with_dem(state, dem.set(walls=change_speed(dem.walls, factor, rate, ramp)))

    def start_phase(self, phase: str, state, loading: Loading | None = None):
        """``state``, at the end of the phase before ``phase`` (of :data:`PHASES`), switched to its start.

        What changes between the phases, written once: ``consolidation`` turns the servos on
        (:meth:`start_consolidation`; ``loading`` unused); ``shear_fine`` starts the strain-controlled
        platens at ``loading.inertial_number``, ramped over ``loading.ramp_strain`` (None: the cell's
        default), ``loading.symmetric`` where set (``start_shear``); ``shear_coarse`` changes to the rate
        of ``loading.coarse_inertial_number`` where it is set (:meth:`change_shear_rate`) and otherwise
        returns ``state`` itself.

        Raises:
          ValueError: a phase not in :data:`PHASES`.
        """
        if phase == "consolidation":
            return self.start_consolidation(state)
        ramp = self.default_ramp_strain if loading.ramp_strain is None else loading.ramp_strain
        if phase == "shear_fine":
            options = {} if loading.symmetric is None else {"symmetric": loading.symmetric}
            return self.start_shear(state, loading.inertial_number, ramp, **options)
        if phase == "shear_coarse":
            if loading.coarse_inertial_number is None:
                return state
            return self.change_shear_rate(
                state, loading.inertial_number, loading.coarse_inertial_number, ramp
            )
        raise ValueError(f"phase = {phase!r}; choose one of {PHASES}.")

    def phase_plan(self, loading: Loading) -> dict[str, tuple[int, int]]:
        """(steps, steps between records) of each phase of :data:`PHASES` under ``loading``.

        Consolidation's steps are its cap (it stops earlier when the cell's stop test holds); the two
        shearing phases' come from :meth:`shear_plan`.
        """
        fine, coarse = self.shear_plan(
            loading.target_axial_strain,
            loading.inertial_number,
            loading.fine_until_strain,
            loading.ramp_strain,
            loading.coarse_inertial_number,
        )
        return {
            "consolidation": (loading.consolidation_max_steps, loading.consolidation_record_every),
            "shear_fine": (fine, loading.record_every_fine),
            "shear_coarse": (coarse, loading.record_every_coarse),
        }

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
        coarse_inertial_number: float | None = None,
        symmetric: bool | None = None,
        steps_done: int = 0,
    ):
        """Stage 2: strain-controlled drained shearing, recorded at two rates (module docstring).

        The shearing phases of :data:`PHASES`, each started by :meth:`start_phase` and run for its steps of
        :meth:`phase_plan`. A run resumed from a checkpoint taken during shearing
        (:class:`membrax.triaxial.stage_checkpoint.StageCheckpoint`) passes the shearing steps its state
        has taken (``steps_done``): the phases it had completed are skipped, the phase it was in is not
        started again, and the rest runs in the chunks the uninterrupted run would have run (each phase runs
        whole records, as the driver rounds its budget).

        Args:
          state: the consolidated state.
          target_axial_strain: axial strain to reach, counted from the start of shearing.
          inertial_number: I, setting the strain rate.
          record_every_fine: steps between records below ``fine_until_strain``.
          fine_until_strain: the end of the fine recording.
          record_every_coarse: steps between records after it.
          chunk_steps: steps per compiled chunk.
          on_chunk: progress callback ``on_chunk(state, records)``.
          ramp_strain: axial strain at which the platens reach full speed (default the cell's), and over
            which they change speed to ``coarse_inertial_number``'s.
          coarse_inertial_number: I after ``fine_until_strain`` (None: ``inertial_number`` throughout).
          symmetric: both platens move (True) or the top one alone (False); None: the cell's default.
          steps_done: shearing steps ``state`` has already taken (0: ``state`` is the consolidated state).

        Returns:
          (state, records) with the records of both recording rates joined (those of the steps not done).

        Raises:
          ValueError: ``steps_done`` negative or beyond the plan's steps.
        """
        loading = Loading(
            consolidation_max_steps=0,  # this stage runs the shearing phases only
            target_axial_strain=target_axial_strain,
            inertial_number=inertial_number,
            fine_until_strain=fine_until_strain,
            ramp_strain=ramp_strain,
            record_every_fine=record_every_fine,
            record_every_coarse=record_every_coarse,
            coarse_inertial_number=coarse_inertial_number,
            symmetric=symmetric,
        )
        plan = self.phase_plan(loading)
        # The steps each phase runs: whole records, as the driver rounds a budget (membrax.driver.drive).
        whole = {phase: math.ceil(plan[phase][0] / plan[phase][1]) * plan[phase][1] for phase in PHASES[1:]}
        if not 0 <= steps_done <= sum(whole.values()):
            raise ValueError(
                f"steps_done = {steps_done}; shearing to this plan takes {sum(whole.values())} steps: give "
                "the steps a resumed state has sheared (0 for a consolidated state)."
            )
        parts = []
        for phase in PHASES[1:]:
            steps, record_every = plan[phase]
            if steps_done > 0 and steps_done >= whole[phase]:
                steps_done -= whole[phase]  # the phase ran to its end before the checkpoint
                continue
            if steps_done == 0:
                state = self.start_phase(phase, state, loading)
            phases = [(steps - steps_done, record_every)]
            state, part = run_phases(self.runner, state, self.params, phases, chunk_steps, on_chunk)
            steps_done = 0
            parts.append(part)
        return state, concatenate_records([part for part in parts if part is not None])
