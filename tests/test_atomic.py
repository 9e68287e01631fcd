"""Atomic output: files and folders get the modes the process umask gives plain ones, and a
failed write leaves the old file as it was."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from egograph.io.atomic import atomic_dir, atomic_path, atomic_write_text

# Each umask in a fresh interpreter: the test process's own umask is left alone.
WRITE_ALL = """
import json, os, stat, sys
from pathlib import Path
os.umask(int(sys.argv[2], 8))
from egograph.io.atomic import atomic_dir, atomic_path, atomic_write_bytes, atomic_write_text
out = Path(sys.argv[1])
atomic_write_text(out / "a.txt", "text")
atomic_write_bytes(out / "b.bin", b"bytes")
with atomic_path(out / "c.png") as tmp:
    tmp.write_bytes(b"png")
with atomic_dir(out / "d") as tmp:
    (tmp / "inner.txt").write_text("x")
atomic_write_text(out / "new" / "e.txt", "parent made on the way")
modes = {str(p.relative_to(out)): oct(stat.S_IMODE(p.stat().st_mode)) for p in sorted(out.rglob("*"))}
print(json.dumps(modes))
"""


@pytest.mark.parametrize("umask, file_mode, dir_mode", [("022", 0o644, 0o755), ("027", 0o640, 0o750)],
                         ids=["umask022", "umask027"])
def test_modes_follow_the_umask(tmp_path, umask, file_mode, dir_mode):
    out = subprocess.run([sys.executable, "-c", WRITE_ALL, str(tmp_path), umask],
                         capture_output=True, text=True, check=True).stdout
    modes = {name: int(mode, 8) for name, mode in json.loads(out).items()}
    for name in ("a.txt", "b.bin", "c.png", "d/inner.txt", "new/e.txt"):
        assert modes[name] == file_mode, name
    for name in ("d", "new"):
        assert modes[name] == dir_mode, name
    assert sorted(modes) == ["a.txt", "b.bin", "c.png", "d", "d/inner.txt", "new", "new/e.txt"]  # no temporaries left


def test_a_umask_changed_later_is_honoured_and_a_replaced_folder_gets_it(tmp_path):
    old = os.umask(0o077)
    try:
        for content in ("old", "new"):
            with atomic_dir(tmp_path / "d") as tmp:
                (tmp / "f.txt").write_text(content)
        atomic_write_text(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert (tmp_path / "d" / "f.txt").read_text() == "new"
    assert stat.S_IMODE((tmp_path / "d").stat().st_mode) == 0o700
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "d"]


class Boom(Exception):
    pass


def test_a_failed_write_leaves_the_old_file(tmp_path):
    target = tmp_path / "out.txt"
    atomic_write_text(target, "good")
    with pytest.raises(Boom):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise Boom
    assert target.read_text() == "good"
    assert sorted(tmp_path.iterdir()) == [target]


def test_a_failed_folder_leaves_the_old_folder(tmp_path):
    target = tmp_path / "d"
    with atomic_dir(target) as tmp:
        (tmp / "f.txt").write_text("good")
    with pytest.raises(Boom):
        with atomic_dir(target) as tmp:
            (tmp / "f.txt").write_text("half")
            raise Boom
    assert (target / "f.txt").read_text() == "good"
    assert sorted(p.name for p in Path(tmp_path).iterdir()) == ["d"]
