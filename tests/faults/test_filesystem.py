"""Cause 3: file system faults are one-line errors; atomic writes get the permissions of a normal write."""

from __future__ import annotations

import os
import stat

import pytest

from optoenc.errors import ConfigError, DataError
from optoenc.rundir import atomic_write_bytes, new_run_dir

from faultkit import main, one_line_error, run


def _mode(p) -> int:
    return stat.S_IMODE(os.stat(p).st_mode)


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_atomic_write_gets_the_umask_permissions(tmp_path, umask):
    old = os.umask(umask)
    try:
        p = atomic_write_bytes(tmp_path / "a" / "f.bin", b"x")
        with open(tmp_path / "plain.bin", "wb") as fh:  # what a normal write gives, side by side
            fh.write(b"x")
    finally:
        os.umask(old)
    assert _mode(p) == _mode(tmp_path / "plain.bin") == 0o666 & ~umask  # mkstemp alone gives 0o600


def test_atomic_write_keeps_the_mode_of_the_file_it_replaces(tmp_path):
    p = tmp_path / "f.txt"
    p.write_text("old")
    os.chmod(p, 0o640)
    atomic_write_bytes(p, b"new")
    assert _mode(p) == 0o640 and p.read_bytes() == b"new"


def test_atomic_write_to_a_folder_is_a_data_error(tmp_path):
    with pytest.raises(DataError, match="is a folder"):
        atomic_write_bytes(tmp_path, b"x")


def test_output_root_that_is_a_file_or_unwritable(tmp_path):
    f = tmp_path / "file"
    f.write_text("")
    with pytest.raises(ConfigError, match="is a file") as err:
        new_run_dir(f, None, "x")
    assert err.value.key == "output.root"
    with pytest.raises(ConfigError) as err:  # /proc refuses new folders even to root
        new_run_dir("/proc/optoenc-runs", None, "x")
    assert err.value.key == "output.root"


def test_cli_run_files_and_pictures_are_readable_by_others(tmp_path, tiny):
    old = os.umask(0o022)
    try:
        proc = run("fit", *tiny, "--output.name=r")
    finally:
        os.umask(old)
    assert proc.returncode == 0, proc.stderr[-2000:]
    r = tmp_path / "runs" / "r"
    for p in [r / "config.yaml", r / "summary.json", r / "metrics.csv", *(r / "pictures").glob("*.png")]:
        assert _mode(p) == 0o644, p


@pytest.mark.parametrize("where", ["file", "proc"])
def test_cli_output_root_file_or_read_only(tmp_path, tiny, where):
    root = tmp_path / "file" if where == "file" else "/proc/optoenc-runs"
    if where == "file":
        root.write_text("")
    line = one_line_error((run if where == "file" else main)("fit", *tiny, f"--output.root={root}"))
    assert "output.root" in line


def test_cli_out_naming_an_existing_folder(tmp_path):
    line = one_line_error(run("psf", "--encoder", "diffuser", "--out", tmp_path))
    assert "--out" in line and "folder" in line
    (tmp_path / "f").write_text("")
    line = one_line_error(main("simulate", "--encoder", "diffuser", "--out", tmp_path / "f"))
    assert "--out" in line
