"""Outputs appear whole or not at all, and never replace a file silently."""

from __future__ import annotations

import os
import stat

import pytest

from factory.core.atomic import atomic_output, check_writable, write_text
from factory.core.errors import OutputError, OutputExistsError


def test_failed_write_leaves_nothing(tmp_path):
    target = tmp_path / "out.nc"
    with pytest.raises(RuntimeError):
        with atomic_output(target, mode="w") as f:
            f.write("G0 X1\n")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_existing_file_is_kept_without_overwrite(tmp_path):
    target = tmp_path / "out.nc"
    target.write_text("mine")
    with pytest.raises(OutputExistsError) as e:
        write_text(target, "theirs")
    assert str(target) in str(e.value)
    assert target.read_text() == "mine"
    write_text(target, "theirs", overwrite=True)
    assert target.read_text() == "theirs"


def test_output_mode_follows_umask(tmp_path):
    old = os.umask(0o022)
    try:
        write_text(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o644


@pytest.mark.parametrize("name", ["afile/p.nc", "afile/deeper/p.nc"])
def test_an_output_whose_folder_is_a_file_is_refused_before_any_work(tmp_path, name):
    (tmp_path / "afile").write_text("mine")
    with pytest.raises(OutputError, match="not a folder") as e:
        check_writable(tmp_path / name, overwrite=True)
    assert e.value.source == str(tmp_path / "afile")
    with pytest.raises(OutputError):
        write_text(tmp_path / name, "G0 X1\n", overwrite=True)
    assert (tmp_path / "afile").read_text() == "mine"


def test_an_output_that_is_a_folder_is_refused(tmp_path):
    with pytest.raises(OutputError, match="is a folder"):
        check_writable(tmp_path, overwrite=True)
