"""Cause 3: file system faults are one-line errors; atomic writes get the permissions of a normal write."""

from __future__ import annotations

import os
import stat

import pytest

from optoenc.errors import ConfigError, DataError
from optoenc.training.rundir import atomic_write_bytes, new_run_dir

from faultkit import one_line_error, run


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


def test_cache_entries_get_the_umask_permissions(tmp_path):
    import torch

    from optoenc.training import cache

    old = os.umask(0o022)
    try:
        path = cache.store("cd" * 32, {"train": torch.ones(2)}, root=str(tmp_path))  # used to be -rw-------
    finally:
        os.umask(old)
    assert _mode(path) == 0o644


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
    with pytest.raises(ConfigError, match="is a file") as err:  # a file in the way further up
        new_run_dir(f / "runs" / "deeper", None, "x")
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


def _refuses_even_root(folder: str) -> bool:
    """True if the kernel refuses to create a folder in ``folder`` whoever asks (sysfs does: EPERM, even to root)."""
    probe = os.path.join(folder, "optoenc-probe")
    try:
        os.mkdir(probe)
    except OSError:
        return True
    os.rmdir(probe)
    return False


@pytest.mark.parametrize("where", ["file", pytest.param("below_file", marks=pytest.mark.slow), "read_only"])
def test_cli_output_root_file_or_read_only(tmp_path, where):
    """A file in the way, or a read-only place: one line naming output.root, and nothing created.

    chmod cannot make a folder unwritable to root (these tests may run as root), so the
    read-only place is one the kernel refuses to everybody: a folder of sysfs.
    """
    (tmp_path / "file").write_text("")
    root = {"file": tmp_path / "file", "below_file": tmp_path / "file" / "runs", "read_only": "/sys/optoenc-runs"}[where]
    if where == "read_only" and not (os.path.isdir("/sys") and _refuses_even_root("/sys")):
        pytest.skip("no sysfs here: no folder that refuses writes even to root")
    line = one_line_error(run("fit", "--encoder", "diffuser", f"--output.root={root}"))
    assert f"output.root = '{root}'" in line
    assert ("is a file" in line) if where != "read_only" else ("cannot create a run directory" in line)
    assert (tmp_path / "file").read_text() == "" and not os.path.exists("/sys/optoenc-runs")  # nothing created


def test_cli_out_naming_an_existing_folder(tmp_path):
    line = one_line_error(run("psf", "--encoder", "diffuser", "--out", tmp_path))
    assert "--out" in line and "folder" in line
    (tmp_path / "f").write_text("")
    line = one_line_error(run("simulate", "--encoder", "diffuser", "--out", tmp_path / "f"))
    assert "--out" in line
