"""A periodic compaction interrupted and resumed from its checkpoint ends where an uninterrupted one does.

``compact_periodic(..., checkpoint_path=...)`` writes its state and records as it goes
(:class:`membrax.triaxial.stage_checkpoint.StageCheckpoint`); killed in either stage (the overload
compression, the unloading) and called again, it ends in the same state and records, to the bit, as a
run straight through, and deletes its checkpoint. A shear resumed mid-way (``StagedTest.shear``'s
``steps_done``) likewise. A file that is not such a checkpoint, or one of another run, is refused with an
error naming it and the fix. All in float32 (users' default) on 60 frictionless spheres.
"""

import jax
import numpy as np
import pytest

from membrax.triaxial.periodic import periodic_test
from membrax.triaxial.periodic_packing import compact_periodic
from membrax.triaxial.stage_checkpoint import StageCheckpoint

DIAMETER = 0.025  # m
#: 60 spheres, d ± 10 %, compressed frictionless to 10 × 100 kPa and unloaded: ~28,000 steps in all.
COMPACTION = {"cell_pressure": 1e5, "friction_coefficient": 0.0, "seed": 1, "tolerance": 1e-3}


def _diameters(count: int = 60, seed: int = 1):
    return np.random.default_rng(seed).uniform(0.9, 1.1, count) * DIAMETER


class Interrupted(Exception):
    """What a killed process would be: raised from the checkpoint report."""


def _interrupt_when(condition):
    """A ``report`` that raises :class:`Interrupted` after the checkpoint whose line meets ``condition``."""
    lines = []

    def report(line):
        lines.append(line)
        if condition(line, len(lines)):
            raise Interrupted(line)

    return report, lines


def _assert_same_bits(first, second):
    for a, b in zip(jax.tree_util.tree_leaves(first), jax.tree_util.tree_leaves(second), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def _ratio(line: str) -> float:
    """The unbalanced-force ratio a checkpoint's line reports (inf where it gives none)."""
    return float(line.rsplit(" ", 1)[-1]) if "ratio" in line else np.inf


def _into(line: str) -> int:
    """The steps into its stage a checkpoint's line reports."""
    return int(line.split("(")[2].split(" ")[0])


def test_an_interrupted_compaction_resumes_to_the_same_bits(tmp_path):
    """Interrupted at its 2nd checkpoint (overload stage, 4,000 steps), at the overload's last chunk (its
    unbalanced-force ratio below the tolerance: the stop test holds, so the resumed stage must not run on)
    and 2,000 steps into the unloading, then resumed to the end: the same positions, box, springs and
    records, to the bit, and the same solid fraction φ as a run straight through; the checkpoint is gone."""
    path = tmp_path / "packing.ckpt"
    diameters = _diameters()
    with jax.enable_x64(False):
        _, straight, straight_records = compact_periodic(diameters, **COMPACTION)
        interruptions = (
            lambda line, count: count == 2,
            lambda line, count: "stage overload" in line and _ratio(line) < COMPACTION["tolerance"],
            lambda line, count: "stage unloading" in line and "(2000 into the stage)" in line,
        )
        for condition in interruptions:
            report, lines = _interrupt_when(condition)
            with pytest.raises(Interrupted):
                compact_periodic(
                    diameters, **COMPACTION, checkpoint_path=path, checkpoint_every_chunks=1, report=report
                )
            assert path.exists()
        report, lines = _interrupt_when(lambda line, count: False)
        _, resumed, resumed_records = compact_periodic(
            diameters, **COMPACTION, checkpoint_path=path, checkpoint_every_chunks=1, report=report
        )
    assert not path.exists()
    assert lines and all("stage unloading" in line for line in lines)  # it went on from the unloading
    _assert_same_bits(resumed, straight)
    _assert_same_bits(resumed_records, straight_records)
    np.testing.assert_array_equal(np.asarray(resumed.position), np.asarray(straight.position))
    assert resumed_records.solid_fraction[-1] == straight_records.solid_fraction[-1]
    assert 0.6 < float(straight_records.solid_fraction[-1]) < 0.66  # near random close packing
    # Both stages ran: the overload's records reach 10 σc, the last ones are at σc.
    assert np.max(np.diagonal(straight_records.stress, axis1=1, axis2=2)) > 9e5
    np.testing.assert_allclose(np.diagonal(straight_records.stress[-1]), 1e5, rtol=0.01)


def test_a_shear_resumed_mid_way_ends_as_one_straight_through(tmp_path):
    """A periodic shear (to 1 % at I = 5e-3, recorded finely to 0.5 %) interrupted after its first chunk
    and again in its coarse phase, each time resumed from the checkpoint: the same state and records, to
    the bit, as one shear straight through."""
    path = tmp_path / "shear.ckpt"
    with jax.enable_x64(False):
        test, packed, _ = compact_periodic(_diameters(), **COMPACTION)
        cell = periodic_test(packed.fraction, packed.box_length, test.particles.radius, 1e5)
        consolidated, _ = cell.consolidate(tolerance=1e-3)
        shear = {
            "target_axial_strain": 0.01,
            "inertial_number": 5e-3,
            "fine_until_strain": 0.005,
            "record_every_fine": 50,
            "record_every_coarse": 100,
            "chunk_steps": 500,
        }
        straight, straight_records = cell.shear(consolidated, **shear)
        fine, coarse = cell.shear_plan(0.01, 5e-3, 0.005)
        fine_steps = -(-fine // 50) * 50  # whole records
        stages = ("consolidation", "shear")
        for after in (0, fine_steps):
            report, _ = _interrupt_when(
                lambda line, count, after=after: "stage shear" in line and _into(line) > after
            )
            checkpoint = StageCheckpoint(path, cell, stages, every_chunks=1, report=report)
            with pytest.raises(Interrupted):
                state, _ = checkpoint.consolidate("consolidation", cell, tolerance=1e-3)
                checkpoint.shear("shear", cell, state, **shear)
        checkpoint = StageCheckpoint(path, cell, stages, every_chunks=1)
        assert checkpoint.progress.stage == "shear"
        state, _ = checkpoint.consolidate("consolidation", cell, tolerance=1e-3)
        resumed, resumed_records = checkpoint.shear("shear", cell, state, **shear)
        checkpoint.remove()
    assert fine_steps > 500 and coarse > 500  # each phase takes several chunks
    assert len(straight_records.step) == fine_steps // 50 + -(-coarse // 100)  # both phases ran
    _assert_same_bits(resumed, straight)
    _assert_same_bits(resumed_records, straight_records)
    assert not path.exists()


def test_a_checkpoint_that_is_not_this_runs_is_refused_naming_it_and_the_fix(tmp_path):
    """A file that is not a checkpoint, a checkpoint of another compaction (another seed) and one of another
    cell (another sphere count) each raise a ValueError naming the file and saying what to do."""
    diameters = _diameters()
    with jax.enable_x64(False):
        garbage = tmp_path / "garbage.ckpt"
        garbage.write_bytes(b"not a checkpoint")
        with pytest.raises(ValueError, match=r"garbage\.ckpt.*not a checkpoint"):
            compact_periodic(diameters, **COMPACTION, checkpoint_path=garbage)

        path = tmp_path / "packing.ckpt"
        report, _ = _interrupt_when(lambda line, count: True)
        with pytest.raises(Interrupted):
            compact_periodic(
                diameters, **COMPACTION, checkpoint_path=path, checkpoint_every_chunks=1, report=report
            )
        other_seed = {**COMPACTION, "seed": 2}
        with pytest.raises(
            ValueError, match=r"packing\.ckpt' was written by another run \(seed = 1 there, 2 here\)"
        ):
            compact_periodic(diameters, **other_seed, checkpoint_path=path)
        with pytest.raises(ValueError, match="delete it to start afresh"):
            compact_periodic(diameters, **other_seed, checkpoint_path=path)

        def cell(count):
            fraction = np.random.default_rng(0).uniform(size=(count, 3)).astype(np.float32)
            return periodic_test(fraction, [0.2, 0.2, 0.2], np.full(count, 0.5 * DIAMETER), 1e5)

        small = tmp_path / "small.ckpt"
        StageCheckpoint(small, cell(20), ("consolidation",)).save("consolidation", 0, cell(20).initial_state)
        with pytest.raises(ValueError, match=r"small\.ckpt' does not fit .* start a fresh run"):
            StageCheckpoint(small, cell(24), ("consolidation",))
        with pytest.raises(ValueError, match=r"small\.ckpt' is of a run with the stages"):
            StageCheckpoint(small, cell(20), ("consolidation", "shear"))
