"""Failures of the membrax command in one line: Ctrl-C (exit status 130, and whether --resume can continue),
a folder that cannot be written and a full disk (exit status 1), with no Python traceback."""

import signal
import subprocess
import sys
import time

import pytest
from helpers import SMALL_SPECIMEN

from membrax import cli
from membrax.config import TriaxialConfig, dump_config_toml
from membrax.runner import CHECKPOINT_NAME


@pytest.mark.slow
def test_ctrl_c_ends_a_run_in_one_line_that_says_how_to_resume(tmp_path):
    """SIGINT to a `membrax run` subprocess once its first checkpoint is written: exit status 130, one line
    on stderr naming the folder and --resume, and the checkpoint left for it."""
    config = TriaxialConfig(
        **SMALL_SPECIMEN,
        name="interrupted",
        membrane_edges_per_diameter=2.5,
        target_axial_strain=0.05,  # long enough to be running when the signal comes
        chunk_steps=500,
        checkpoint_every_chunks=1,
    )
    path = tmp_path / "config.toml"
    path.write_text(dump_config_toml(config))
    out = tmp_path / "out"
    command = [sys.executable, "-m", "membrax.cli", "run", str(path), "--out", str(out), "--no-progress"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    started = time.monotonic()
    while (
        not (out / CHECKPOINT_NAME).exists() and process.poll() is None and time.monotonic() - started < 600
    ):
        time.sleep(0.2)
    assert process.poll() is None, process.communicate()
    process.send_signal(signal.SIGINT)
    _, error = process.communicate(timeout=600)
    assert process.returncode == 130
    lines = error.strip().splitlines()
    resume = "run the same command with --resume to continue"
    assert lines == [f"membrax: interrupted; the checkpoint in {out} is kept: {resume}"]
    assert (out / CHECKPOINT_NAME).exists()


def test_an_unwritable_or_full_folder_ends_in_one_line(tmp_path, capsys, monkeypatch):
    """The write of `membrax correct` failing as a read-only folder and a full disk make it fail (root
    ignores permissions, so the operating system's errors are raised where membrax writes)."""
    import errno

    from calibrate import correct, evaluate, lab
    from membrax.io import files

    with correct.example_record_path() as record:
        argv = ["correct", str(record), "--out", str(tmp_path / "x.csv"), "--no-plot"]
        argv += [
            item
            for flag, value in zip(
                evaluate.SPECIMEN_FLAGS,
                evaluate.example_arguments(lab.read_lab_record(record).comments),
                strict=True,
            )
            for item in (flag, repr(value))
        ]
        for raised, words in (
            (
                PermissionError(errno.EACCES, "Permission denied", str(tmp_path / "x.csv")),
                "permission denied",
            ),
            (OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "x.csv")), "no space left"),
        ):

            def refuse(path, data, raised=raised):
                raise raised

            monkeypatch.setattr(files, "atomic_write_bytes", refuse)
            assert cli.main(argv) == 1
            error = capsys.readouterr().err.strip().splitlines()
            assert len(error) == 1 and error[0].startswith(f"membrax: {tmp_path / 'x.csv'}: {words}")
            assert not (tmp_path / "x.csv").exists()
