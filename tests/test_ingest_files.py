"""ingest.files: the one atomic-write helper (temp file beside the target, fsync, os.replace)."""

from __future__ import annotations

import os
import stat
import sys

import pytest

from ingest.files import atomic_write, atomic_write_bytes, atomic_write_text


def _leftovers(directory):
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(".tmp"))


def test_writes_bytes_text_and_through_a_writer(tmp_path):
    target = tmp_path / "out.bin"
    assert atomic_write_bytes(target, b"\x00\x01abc") == target
    assert target.read_bytes() == b"\x00\x01abc"
    text = tmp_path / "out.txt"
    atomic_write_text(str(text), "h\u00e9\nline 2\n")  # str paths accepted; newlines written as given
    assert text.read_bytes() == "h\u00e9\nline 2\n".encode()
    table = tmp_path / "out.csv"
    seen = []

    def write(temp):
        seen.append(temp)
        temp.write_text("a,b\n1,2\n")

    assert atomic_write(table, write) == table
    assert table.read_text() == "a,b\n1,2\n"
    (temp,) = seen  # the writer got a temporary file in the same directory, not the target
    assert temp.parent == tmp_path and temp != table and temp.name.startswith(".out.csv.")
    assert _leftovers(tmp_path) == []


def test_replaces_existing_content_and_keeps_its_mode(tmp_path):
    target = tmp_path / "CALIB.json"
    target.write_text("old")
    os.chmod(target, 0o640)
    atomic_write_text(target, "new")
    assert target.read_text() == "new"
    if sys.platform != "win32":
        assert stat.S_IMODE(target.stat().st_mode) == 0o640


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX permission bits")
def test_new_file_gets_the_umask_mode_not_the_temp_file_0600(tmp_path):
    mask = os.umask(0o022)
    try:
        atomic_write_bytes(tmp_path / "new.ulg", b"x")
    finally:
        os.umask(mask)
    assert stat.S_IMODE((tmp_path / "new.ulg").stat().st_mode) == 0o644


def test_failing_writer_keeps_the_old_content_and_leaves_no_temp_file(tmp_path):
    target = tmp_path / "states.parquet"
    target.write_bytes(b"old content")

    def failing(temp):
        temp.write_bytes(b"half writ")
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError, match="disk on fire"):
        atomic_write(target, failing)
    assert target.read_bytes() == b"old content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["states.parquet"]


def test_interrupt_also_cleans_up_and_a_new_target_is_not_created(tmp_path):
    def interrupted(temp):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(tmp_path / "never.csv", interrupted)
    assert list(tmp_path.iterdir()) == []


def test_missing_directory_raises_a_clear_error(tmp_path):
    target = tmp_path / "missing_dir" / "out.csv"
    with pytest.raises(FileNotFoundError, match="does not exist") as info:
        atomic_write_bytes(target, b"x")
    assert info.value.filename == str(target)
    assert str(tmp_path / "missing_dir") in info.value.strerror
    assert not (tmp_path / "missing_dir").exists()


def test_parent_that_is_a_file_raises(tmp_path):
    (tmp_path / "plain").write_text("")
    with pytest.raises(NotADirectoryError, match="not a directory"):
        atomic_write_text(tmp_path / "plain" / "out.txt", "x")
