"""The shared argument checks and atomic writes (sb3_latentswarm.utils.checks / .atomic)."""

import math
import os

import numpy as np
import pytest

from sb3_latentswarm.utils import atomic
from sb3_latentswarm.utils.checks import check_bool, check_choice, check_float, check_int


def test_check_int_accepts_numpy_and_refuses_bool_and_range():
    assert check_int("n", np.int64(3), 1) == 3
    with pytest.raises(TypeError, match="n must be an int"):
        check_int("n", True, 0)
    with pytest.raises(ValueError, match=r"n must be an int in \[1, 5\], got 6"):
        check_int("n", 6, 1, 5)


def test_check_float_refuses_nan_inf_strings_and_open_bounds():
    assert check_float("lr", np.float32(0.5), 0.0, low_open=True) == 0.5
    for bad in (math.nan, math.inf, -1.0, 0.0):
        with pytest.raises(ValueError, match="lr must be a finite number in"):
            check_float("lr", bad, 0.0, low_open=True)
    with pytest.raises(TypeError, match="lr must be a number"):
        check_float("lr", "0.1")


def test_check_bool_and_choice():
    assert check_bool("flag", np.bool_(True)) is True
    with pytest.raises(TypeError):
        check_bool("flag", 1)
    assert check_choice("mode", "a", ("a", "b")) == "a"
    with pytest.raises(ValueError, match="mode must be one of 'a', 'b'; got 'c'"):
        check_choice("mode", "c", ("a", "b"))
    with pytest.raises(ValueError):
        check_choice("mode", ["unhashable"], {"a"})


def test_atomic_write_keeps_the_old_file_when_writing_fails(tmp_path):
    target = tmp_path / "table.csv"
    atomic.write_text(target, "old\n")
    with pytest.raises(RuntimeError):
        with atomic.atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("disk full")
    assert target.read_text() == "old\n"
    assert sorted(os.listdir(tmp_path)) == ["table.csv"]
    atomic.write_json(target, {"a": 1})
    assert target.read_text().startswith("{")


def test_atomic_files_get_the_umask_mode_or_keep_the_replaced_files_mode(tmp_path):
    old_umask = os.umask(0o022)
    try:
        atomic.write_text(tmp_path / "new.txt", "x")
        assert (tmp_path / "new.txt").stat().st_mode & 0o777 == 0o644  # as open(path, "w") would, not mkstemp's 0o600
        os.umask(0o077)
        atomic.write_bytes(tmp_path / "private.bin", b"x")
        assert (tmp_path / "private.bin").stat().st_mode & 0o777 == 0o600
        os.chmod(tmp_path / "new.txt", 0o640)
        atomic.write_text(tmp_path / "new.txt", "y")  # a replaced file keeps its mode
        assert (tmp_path / "new.txt").stat().st_mode & 0o777 == 0o640
    finally:
        os.umask(old_umask)


def test_probe_writable_refuses_a_file_and_an_unwritable_folder(tmp_path):
    atomic.probe_writable(tmp_path / "new" / "deep", room_bytes=1024)
    assert (tmp_path / "new" / "deep").is_dir() and not os.listdir(tmp_path / "new" / "deep")
    a_file = tmp_path / "f"
    a_file.write_text("x")
    with pytest.raises(ValueError, match="is an existing file"):
        atomic.probe_writable(a_file)
    if os.geteuid() != 0:  # root writes through permission bits
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(ValueError, match="not writable"):
            atomic.probe_writable(locked)
