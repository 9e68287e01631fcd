"""Atomic output: files and folders get the modes the process umask gives plain ones, and a
failed write leaves the old file as it was."""

from __future__ import annotations

import json
import os
import re
import shutil
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


# ------------------------------------------------------------------ replacing a folder

# A writer that SIGKILLs itself at one moment of replacing the folder ARGV[1] ("old" -> "new").
KILLED = """
import os, shutil, signal, sys
from pathlib import Path
from egograph.io import atomic
moment = sys.argv[2]
if moment != "exchange":
    atomic.exchange = lambda a, b: False
replace, rmtree = os.replace, shutil.rmtree
def replace_then_die(a, b):  # the fallback's second rename never happens
    if Path(a).name.endswith(".tmp"):
        os.kill(os.getpid(), signal.SIGKILL)
    replace(a, b)
def die(*args, **kw):  # before the swapped-out old folder is removed
    os.kill(os.getpid(), signal.SIGKILL)
if moment == "between renames":
    os.replace = replace_then_die
else:
    shutil.rmtree = die
with atomic.atomic_dir(sys.argv[1]) as tmp:
    (tmp / "f.txt").write_text("new")
"""


def folder_text(path: Path) -> dict[str, str]:
    return {p.name: p.read_text() for p in path.iterdir()}


def test_replacing_a_folder_is_one_exchange(tmp_path, monkeypatch):
    from egograph.io import atomic

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "in_a").touch()
    if not atomic.exchange(tmp_path / "a", tmp_path / "b"):
        pytest.skip("renameat2(RENAME_EXCHANGE) is not available here")
    assert [p.name for p in (tmp_path / "b").iterdir()] == ["in_a"]
    shutil.rmtree(tmp_path / "a")
    shutil.rmtree(tmp_path / "b")
    calls = []
    real = atomic.exchange
    monkeypatch.setattr(atomic, "exchange", lambda a, b: calls.append((Path(a).name, Path(b).name)) or real(a, b))
    target = tmp_path / "d"
    for content in ("old", "new"):
        with atomic_dir(target) as tmp:
            (tmp / "f.txt").write_text(content)
    assert len(calls) == 1 and calls[0][1] == "d" and calls[0][0].startswith(f".d.{os.getpid()}.")
    assert folder_text(target) == {"f.txt": "new"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_without_the_exchange_the_folder_is_replaced_by_two_renames(tmp_path, monkeypatch):
    from egograph.io import atomic

    monkeypatch.setattr(atomic, "exchange", lambda a, b: False)
    target = tmp_path / "d"
    for content in ("old", "new"):
        with atomic_dir(target) as tmp:
            (tmp / "f.txt").write_text(content)
    assert folder_text(target) == {"f.txt": "new"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]


TMP = "<the writer's temporary>"
AFTER_KILL = {  # moment -> what is left: name -> content of its f.txt (None: the lock file)
    "exchange": {TMP: "old", ".d.lock": None, "d": "new"},
    "between renames": {TMP: "new", ".d.lock": None, ".d.old": "old"},
    "after the renames": {".d.lock": None, ".d.old": "old", "d": "new"},
}


@pytest.mark.parametrize("moment", list(AFTER_KILL))
def test_a_kill_while_replacing_loses_neither_folder(tmp_path, moment):
    """Killed after the exchange, NAME is the new folder; killed between the fallback's renames, NAME
    is missing and ``.NAME.old`` whole, and the next run puts it back first. Either way the next run
    removes what is left, even when it fails itself."""
    target = tmp_path / "d"
    with atomic_dir(target) as tmp:
        (tmp / "f.txt").write_text("old")
    assert subprocess.run([sys.executable, "-c", KILLED, str(target), moment]).returncode == -9
    left = {}
    for p in tmp_path.iterdir():
        name = TMP if re.fullmatch(r"\.d\.[0-9]+\.\w+\.tmp", p.name) else p.name  # named after its writer
        left[name] = (p / "f.txt").read_text() if p.is_dir() else None
    assert left == AFTER_KILL[moment]
    with pytest.warns(UserWarning, match="cleaned up after an interrupted run"):
        with pytest.raises(Boom):
            with atomic_dir(target) as tmp:
                raise Boom
    assert folder_text(target) == {"f.txt": "old" if moment == "between renames" else "new"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]


@pytest.mark.parametrize("kind", ["file", "link", "dangling link"])
def test_a_folder_replacing_a_file_or_a_link_leaves_nothing_behind(tmp_path, kind):
    target = tmp_path / "d"
    if kind == "file":
        target.write_text("a file")
    else:
        (tmp_path / "elsewhere").mkdir()
        target.symlink_to(tmp_path / ("elsewhere" if kind == "link" else "nowhere"))
    with atomic_dir(target) as tmp:
        (tmp / "f.txt").write_text("new")
    assert not target.is_symlink() and folder_text(target) == {"f.txt": "new"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"] + (["elsewhere"] if kind != "file" else [])


def test_a_nested_write_of_the_same_output_keeps_the_outer_temporary(tmp_path):
    target = tmp_path / "d"
    with atomic_dir(target) as outer:
        (outer / "f.txt").write_text("outer")
        with atomic_dir(target) as inner:  # same thread: re-enters the lock; must not see `outer` as a leftover
            (inner / "f.txt").write_text("inner")
        assert (outer / "f.txt").read_text() == "outer"
    assert folder_text(target) == {"f.txt": "outer"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]
