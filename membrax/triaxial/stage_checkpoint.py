"""Checkpoints of one cell's stages: a long single-cell run resumed after an interruption, to the same bits.

Contract. A :class:`StageCheckpoint` keeps one ``.npz`` (:func:`membrax.io.save_checkpoint`) for a run of
one periodic cell (:class:`membrax.triaxial.periodic.PeriodicTest`) made of named stages run one after
another, each a :meth:`~membrax.triaxial.protocol.StagedTest.consolidate` or a
:meth:`~membrax.triaxial.protocol.StagedTest.shear` driven by the chunk driver (:mod:`membrax.driver`)
and watched through its ``on_chunk`` callback. The file holds the state after the last accepted chunk;
in ``host``, the stage it is in, the step at which that stage began, the records of every stage so far,
the seconds spent so far (in all, and at each stage's end), the shape of the state's neighbour list
(:meth:`PeriodicTest.list_shape`, from which :meth:`PeriodicTest.template` makes the template
:func:`membrax.io.load_checkpoint` fills) and the run's ``signature`` (the settings that must agree for a
resume).

- :meth:`StageCheckpoint.consolidate` and :meth:`StageCheckpoint.shear` run a stage: afresh, from the
  checkpoint's state for the remaining steps (the stage it was in), or not at all (a stage it had
  completed: its records are the checkpoint's); a checkpoint is written after a chunk once
  ``every_chunks`` chunks or ``every_seconds`` seconds have passed since the last, whichever comes first,
  and at each stage's end (then naming the next stage, which starts from that state);
- :meth:`StageCheckpoint.remove` deletes the file once the run is complete.

A resumed stage runs its remaining steps in chunks of the same size and at the same boundaries as the
uninterrupted run, so a resumed run ends in the same state and records, to the bit
(``tests/test_stage_checkpoint.py``). What it loses to an interruption is the chunks since the last
checkpoint.

Errors: a file that is not a checkpoint, or is damaged, raises :class:`ValueError` naming it
(:func:`membrax.io.load_checkpoint`); so does a checkpoint of another run (another signature, another
list of stages, another particle count or precision), saying to delete it or to resume with the settings
that wrote it.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import numpy as np

from membrax.defaults import default_consolidation_tolerance
from membrax.driver import concatenate_records
from membrax.io import load_checkpoint, read_checkpoint_host, save_checkpoint

__all__ = ["StageCheckpoint", "StageProgress"]

#: ``host["kind"]`` of a stage checkpoint (a checkpoint of :mod:`membrax.runner` has none).
STAGE_CHECKPOINT_KIND = "membrax-stage-checkpoint"


@dataclasses.dataclass
class StageProgress:
    """Where a staged run stands (what a stage checkpoint holds).

    Attributes:
      stage: the stage it is in (one of the run's stages).
      stage_start_step: ``state.step`` at the start of that stage.
      state: the state after the last accepted chunk (or at the stage's start).
      records: the records of each stage run so far, by stage (the current one's up to ``state``).
      elapsed_seconds: wall-clock seconds spent up to the checkpoint, in all the processes that ran it.
      stage_seconds: ``elapsed_seconds`` at the end of each completed stage, by stage.
    """

    stage: str
    stage_start_step: int
    state: object
    records: dict
    elapsed_seconds: float = 0.0
    stage_seconds: dict = dataclasses.field(default_factory=dict)


class StageCheckpoint:
    """The checkpoint of a staged run of one periodic cell (module docstring).

    Args:
      path: the checkpoint file (``.npz`` or any name; its folder is made if missing).
      test: the cell (:class:`membrax.triaxial.periodic.PeriodicTest`) whose states are saved; its
        ``initial_state`` and ``template`` make the template of a load.
      stages: the names of the run's stages, in order.
      signature: JSON-able settings of the run that a resume must share (sizes, σc, seed, ...), checked
        against the checkpoint's.
      every_chunks: write a checkpoint after this many chunks (None: by time alone).
      every_seconds: write a checkpoint once this many seconds have passed since the last (None: by chunks
        alone); with both None, at stage ends only.
      report: ``report(line)``, called with a line after each checkpoint written (e.g. ``print``).

    Raises:
      ValueError: if ``path`` exists and is not a stage checkpoint of this run (module docstring).
    """

    def __init__(
        self,
        path,
        test,
        stages: Sequence[str],
        signature: dict | None = None,
        every_chunks: int | None = None,
        every_seconds: float | None = 120.0,
        report: Callable[[str], None] | None = None,
    ):
        if every_chunks is not None and every_chunks < 1:
            raise ValueError(f"every_chunks = {every_chunks}; give a positive number of chunks, or None.")
        if every_seconds is not None and every_seconds < 0:
            raise ValueError(f"every_seconds = {every_seconds}; give seconds ≥ 0, or None.")
        self.path = Path(path)
        self.test = test
        self.stages = tuple(stages)
        self.signature = json.loads(json.dumps(signature or {}))
        self.every_chunks = every_chunks
        self.every_seconds = every_seconds
        self.report = report
        self.records: dict = {}
        #: ``elapsed_seconds`` at the end of each completed stage, by stage.
        self.stage_seconds: dict = {}
        self._chunks_since_save = 0
        self._clock = self._last_save = time.monotonic()
        self._elapsed_before = 0.0
        self.progress = self._load() if self.path.exists() else None
        if self.progress is not None:
            self.records = dict(self.progress.records)
            self.stage_seconds = dict(self.progress.stage_seconds)
            self._elapsed_before = self.progress.elapsed_seconds

    @property
    def elapsed_seconds(self) -> float:
        """Wall-clock seconds the run has taken: those kept by the checkpoint it resumed and this process's.

        The time between an interrupted process's last checkpoint and its end is not counted.
        """
        return self._elapsed_before + time.monotonic() - self._clock

    # ------------------------------------------------------------------------------------------- loading

    def _fail(self, what: str) -> ValueError:
        return ValueError(
            f"checkpoint '{self.path}' {what}; delete it to start afresh, or resume with the settings that "
            "wrote it."
        )

    def _load(self) -> StageProgress:
        """The progress held by the file at ``path`` (checked against this run)."""
        host = read_checkpoint_host(self.path)
        if not isinstance(host, dict) or host.get("kind") != STAGE_CHECKPOINT_KIND:
            raise self._fail("is not a stage checkpoint (membrax.triaxial.stage_checkpoint)")
        if host.get("stages") != list(self.stages):
            raise self._fail(f"is of a run with the stages {host.get('stages')}, not {list(self.stages)}")
        saved = host.get("signature", {})
        for key in sorted(set(saved) | set(self.signature)):
            if saved.get(key) != self.signature.get(key):
                raise self._fail(
                    f"was written by another run ({key} = {saved.get(key)!r} there, "
                    f"{self.signature.get(key)!r} here)"
                )
        try:
            template = self.test.template(**host["list_shape"])
        except (KeyError, TypeError) as error:
            raise self._fail(f"is damaged: its list shape is unreadable ({error!r})") from error
        state, host = load_checkpoint(self.path, template)
        records_structure = jax.tree_util.tree_structure(
            jax.eval_shape(self.test.runner.record_fn, self.test.initial_state, self.test.params)
        )
        try:
            records = {}
            for stage in host["record_stages"]:
                leaves = [host[f"records__{stage}__{i:03d}"] for i in range(records_structure.num_leaves)]
                records[stage] = jax.tree_util.tree_unflatten(records_structure, leaves)
            if host["stage"] not in self.stages:
                raise KeyError(host["stage"])
            return StageProgress(
                host["stage"],
                int(host["stage_start_step"]),
                state,
                records,
                float(host.get("elapsed_seconds", 0.0)),
                dict(host.get("stage_seconds", {})),
            )
        except (KeyError, TypeError, ValueError) as error:
            raise self._fail(f"is damaged: its stage or records are unreadable ({error!r})") from error

    # ------------------------------------------------------------------------------------------- writing

    def save(self, stage: str, stage_start_step: int, state) -> None:
        """Write a checkpoint: ``state`` in ``stage`` (begun at ``stage_start_step``), the records so far."""
        host = {
            "kind": STAGE_CHECKPOINT_KIND,
            "stages": list(self.stages),
            "signature": self.signature,
            "stage": stage,
            "stage_start_step": int(stage_start_step),
            "list_shape": self.test.list_shape(state),
            "record_stages": [name for name in self.stages if self.records.get(name) is not None],
            "elapsed_seconds": self.elapsed_seconds,
            "stage_seconds": self.stage_seconds,
        }
        for name in host["record_stages"]:
            for i, leaf in enumerate(jax.tree_util.tree_leaves(self.records[name])):
                host[f"records__{name}__{i:03d}"] = np.asarray(leaf)
        save_checkpoint(self.path, state, host)
        self._chunks_since_save, self._last_save = 0, time.monotonic()
        if self.report is not None:
            step = int(state.step)
            ratio = getattr(self.records.get(stage), "unbalanced_force_ratio", None)
            detail = "" if ratio is None or len(ratio) == 0 else f", unbalanced-force ratio {ratio[-1]:.2e}"
            number = f"{self.stages.index(stage) + 1}/{len(self.stages)}"
            self.report(
                f"checkpoint {self.path.name}: stage {stage} ({number}), step {step} "
                f"({step - int(stage_start_step)} into the stage){detail}"
            )

    def remove(self) -> None:
        """Delete the checkpoint (the run is complete)."""
        self.path.unlink(missing_ok=True)
        self.progress = None

    def _due(self) -> bool:
        if self.every_chunks is not None and self._chunks_since_save >= self.every_chunks:
            return True
        return self.every_seconds is not None and time.monotonic() - self._last_save >= self.every_seconds

    def _watch(self, stage: str, stage_start_step: int, on_chunk: Callable | None):
        """The ``on_chunk`` of ``stage``: its records gathered, a checkpoint when one is due."""
        earlier = self.records.get(stage)
        chunks = [] if earlier is None else [earlier]

        def watch(state, records):
            chunks.append(records)
            self._chunks_since_save += 1
            if self._due():
                self.records[stage] = concatenate_records(chunks)
                chunks[:] = [self.records[stage]]  # joined: the next join starts from it
                self.save(stage, stage_start_step, state)
            if on_chunk is not None:
                on_chunk(state, records)

        return watch

    # ------------------------------------------------------------------------------------------- stages

    def _begin(self, stage: str, state):
        """(where the stage begins: "fresh", "resume" or "done"; the state it begins from; its start step)."""
        if stage not in self.stages:
            raise ValueError(f"stage {stage!r} is not one of this run's stages {self.stages}.")
        if self.progress is None:
            return "fresh", state, None
        here, there = self.stages.index(stage), self.stages.index(self.progress.stage)
        if here < there:
            return "done", self.progress.state, None
        if here > there:
            return "fresh", state, None
        return "resume", self.progress.state, self.progress.stage_start_step

    def _end(self, stage: str, state, records) -> None:
        """The stage's records kept; a checkpoint at its end naming the next stage (none after the last)."""
        self.records[stage] = records
        self.stage_seconds[stage] = self.elapsed_seconds
        self.progress = None  # the stages after this one start afresh from the state passed on
        index = self.stages.index(stage)
        if index + 1 < len(self.stages):
            self.save(self.stages[index + 1], int(state.step), state)

    def consolidate(
        self,
        stage: str,
        cell,
        state=None,
        tolerance: float | None = None,
        max_steps: int = 200_000,
        **options,
    ):
        """``cell.consolidate(state, tolerance, max_steps, **options)`` as the stage ``stage``, checkpointed.

        Resumed, it goes on from the checkpoint's state for the steps of ``max_steps`` left, unless the
        records so far already meet the stop test (the last chunk before the checkpoint ended the stage); a
        stage the checkpoint had completed is not run and returns the checkpoint's state and its records.

        Args:
          stage: the stage's name (one of ``stages``).
          cell: the cell that runs it (a :class:`membrax.triaxial.protocol.StagedTest`, e.g. the
            checkpoint's ``test`` or a copy at another σc).
          state: the starting state of a fresh stage (None: ``cell``'s initial state).
          tolerance: the unbalanced-force ratio to reach (:meth:`StagedTest.consolidate`).
          max_steps: the stage's step budget.
          **options: further arguments of :meth:`StagedTest.consolidate` (``chunk_steps``, ``on_chunk``,
            stop criteria).

        Returns:
          (state, records) of the stage, as :meth:`StagedTest.consolidate`'s.
        """
        where, state, start_step = self._begin(stage, state)
        if where == "done":
            return state, self.records.get(stage)
        state = cell.initial_state if state is None else state
        start_step = int(state.step) if start_step is None else start_step
        on_chunk = self._watch(stage, start_step, options.pop("on_chunk", None))
        earlier = self.records.get(stage) if where == "resume" else None
        if tolerance is None:  # StagedTest.consolidate's default, which the stop test below needs too
            dtype = cell.runner.dem_of(state).position.dtype
            tolerance = default_consolidation_tolerance(cell.cell, dtype == np.float64)
        criteria = {k: v for k, v in options.items() if k not in ("chunk_steps", "record_every")}
        if earlier is None or not cell.is_consolidated(earlier, tolerance, **criteria):
            left = max_steps - (int(state.step) - start_step)
            if left > 0:
                state, records = cell.consolidate(
                    state, tolerance=tolerance, max_steps=left, on_chunk=on_chunk, **options
                )
                earlier = concatenate_records([part for part in (earlier, records) if part is not None])
        self._end(stage, state, earlier)
        return state, earlier

    def shear(self, stage: str, cell, state, **options):
        """``cell.shear(state, **options)`` as the stage ``stage``, checkpointed.

        Resumed, it goes on from the checkpoint's state with the shearing steps already taken
        (:meth:`StagedTest.shear`'s ``steps_done``); a stage the checkpoint had completed is not run.

        Args:
          stage: the stage's name (one of ``stages``).
          cell: the cell that runs it.
          state: the consolidated state of a fresh stage.
          **options: arguments of :meth:`StagedTest.shear` (target strain, inertial number, ``on_chunk``).

        Returns:
          (state, records) of the stage, as :meth:`StagedTest.shear`'s.
        """
        where, state, start_step = self._begin(stage, state)
        if where == "done":
            return state, self.records.get(stage)
        start_step = int(state.step) if start_step is None else start_step
        on_chunk = self._watch(stage, start_step, options.pop("on_chunk", None))
        earlier = self.records.get(stage) if where == "resume" else None
        state, records = cell.shear(
            state, steps_done=int(state.step) - start_step, on_chunk=on_chunk, **options
        )
        records = concatenate_records([part for part in (earlier, records) if part is not None])
        self._end(stage, state, records)
        return state, records
