"""One writer per output: the advisory lock ``atomic_dir``/``atomic_path`` hold while they build and
rename, how a second writer fails (or waits), and the cleanup of what killed writers left behind."""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import pytest

from egograph.core.errors import ConfigError, InputError
from egograph.io.atomic import WAIT_ENV, LeftoverWarning, atomic_dir, atomic_write_text, output_lock

HOLD = """
import sys
from egograph.io.atomic import output_lock
with output_lock(sys.argv[1]):
    print("held", flush=True)
    sys.stdin.readline()
"""

BUSY = "another egograph run is writing this output (pid {}); wait for it or choose another --out"


@contextlib.contextmanager
def held_elsewhere(path: Path):
    """Another process holding the output lock of ``path`` until the block ends (or ``release()``)."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline() == "held\n"
        yield proc
    finally:
        release(proc)


def release(proc: subprocess.Popen) -> None:
    if proc.stdin and not proc.stdin.closed:
        proc.stdin.close()  # the holder's readline returns: it releases and exits
    proc.wait(timeout=30)


def dead_pid() -> int:
    """The pid of a process that has ended (and been reaped)."""
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    return int(proc.stdout)


def names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def write_dir(target: Path, text: str, **kw) -> None:
    with atomic_dir(target, **kw) as tmp:
        (tmp / "f.txt").write_text(text)


# ------------------------------------------------------------------ the lock


def test_a_second_writer_fails_at_once_naming_the_holder(tmp_path):
    target = tmp_path / "d"
    write_dir(target, "old")
    with held_elsewhere(target) as holder:
        t0 = time.monotonic()
        with pytest.raises(InputError) as err:
            write_dir(target, "new")
        assert time.monotonic() - t0 < 1.0
        assert str(err.value) == f"{target}: {BUSY.format(holder.pid)}"
        assert names(tmp_path) == [".d.lock", "d"]  # nothing of the refused run
    assert (target / "f.txt").read_text() == "old"
    assert names(tmp_path) == ["d"]  # the holder removed its lock file


def test_a_file_writer_is_locked_out_too(tmp_path):
    target = tmp_path / "a.txt"
    with held_elsewhere(target) as holder:
        with pytest.raises(InputError, match=f"pid {holder.pid}"):
            atomic_write_text(target, "x")
    assert names(tmp_path) == []
    atomic_write_text(target, "x")
    assert names(tmp_path) == ["a.txt"]


def test_a_writer_waits_when_asked(tmp_path, monkeypatch):
    target = tmp_path / "d"
    with held_elsewhere(target) as holder:
        threading.Timer(0.5, release, [holder]).start()
        t0 = time.monotonic()
        write_dir(target, "after the holder", wait=30)
        assert time.monotonic() - t0 >= 0.4
    with held_elsewhere(target) as holder:  # the environment variable sets the default
        monkeypatch.setenv(WAIT_ENV, "30")
        threading.Timer(0.3, release, [holder]).start()
        write_dir(target, "waited again")
    assert (target / "f.txt").read_text() == "waited again"
    with held_elsewhere(target) as holder:  # a wait that runs out
        monkeypatch.setenv(WAIT_ENV, "0.3")
        t0 = time.monotonic()
        with pytest.raises(InputError, match=f"pid {holder.pid}"):
            write_dir(target, "never")
        assert 0.25 <= time.monotonic() - t0 < 5
    for bad in ("soon", "-1", "nan"):
        monkeypatch.setenv(WAIT_ENV, bad)
        with pytest.raises(ConfigError, match=f"{WAIT_ENV}='{bad}': expected a number of seconds"):
            write_dir(target, "x")
    assert names(tmp_path) == ["d"]


def test_the_lock_is_reentrant_in_one_thread_and_exclusive_between_threads(tmp_path):
    target = tmp_path / "d"
    with output_lock(target):  # a step holding it around its run, its write inside
        write_dir(target, "inside")
        failed = []
        t = threading.Thread(target=lambda: failed.append(pytest.raises(InputError, write_dir, target, "x")))
        t.start()
        t.join()
        assert f"pid {os.getpid()}" in str(failed[0].value)
    assert names(tmp_path) == ["d"]


def test_writers_take_turns(tmp_path):
    """Threads and processes writing one output with ``wait``: never two inside at once, even while
    each release removes the lock file that the next one may already have opened."""
    target = tmp_path / "d"
    log = tmp_path / "log"
    script = """
import os, sys, time
from egograph.io.atomic import atomic_dir
for i in range(15):
    with atomic_dir(sys.argv[1], wait=60) as tmp:
        with open(sys.argv[2], "a") as f: f.write(f"in {os.getpid()}\\n")
        (tmp / "f.txt").write_text(str(os.getpid()))
        time.sleep(0.002)
        with open(sys.argv[2], "a") as f: f.write(f"out {os.getpid()}\\n")
"""
    procs = [subprocess.Popen([sys.executable, "-c", script, str(target), str(log)]) for _ in range(3)]
    inside, most = [0], [0]
    guard = threading.Lock()

    def writer():
        for _ in range(20):
            with atomic_dir(target, wait=60) as tmp:
                with guard:
                    inside[0] += 1
                    most[0] = max(most[0], inside[0])
                (tmp / "f.txt").write_text("thread")
                time.sleep(0.001)
                with guard:
                    inside[0] -= 1

    threads = [threading.Thread(target=writer) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for p in procs:
        assert p.wait(timeout=120) == 0
    assert most[0] == 1
    lines = log.read_text().split("\n")[:-1]
    assert len(lines) == 90
    for enter, leave in zip(lines[::2], lines[1::2]):
        assert enter.startswith("in ") and leave == "out " + enter[3:]
    assert names(tmp_path) == ["d", "log"]
    assert names(target) == ["f.txt"]


def test_a_killed_writers_lock_file_is_taken_over(tmp_path):
    target = tmp_path / "d"
    (tmp_path / ".d.lock").write_text(f"{dead_pid()}0000\n")  # longer than a pid of ours
    write_dir(target, "x")
    assert names(tmp_path) == ["d"]


# ------------------------------------------------------------------ leftovers


def test_leftovers_of_dead_writers_are_removed_with_one_warning(tmp_path):
    target = tmp_path / "d"
    write_dir(target, "old")
    dead = dead_pid()
    live = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        stale_dir = tmp_path / f".d.{dead}.abc_123.tmp"
        stale_dir.mkdir()
        (stale_dir / "half.txt").write_text("half")
        (tmp_path / f".d.{dead}.zzzzzzzz.tmp").write_text("file")
        (tmp_path / f".d.{dead}.yyyyyyyy.tmp").write_text("file")
        (tmp_path / f".d.{dead}.link.tmp").symlink_to(target)  # removed, never followed
        keep = [f".d.{live.pid}.qqqqqqqq.tmp",  # its writer is alive
                ".d.abcdefgh.tmp", f".d.{dead}.tmp",  # not ours to judge (no pid, no random part)
                f".d2.{dead}.abc.tmp", f".d.x.{dead}.abc.tmp", "d.txt"]  # another output's
        for name in keep:
            (tmp_path / name).write_text("keep")
        with pytest.warns(LeftoverWarning) as said:
            write_dir(target, "new")
        assert len(said) == 1
        message = str(said[0].message)
        assert "\n" not in message and message.startswith(f"{target}: cleaned up after an interrupted run: ")
        assert f".d.{dead}.abc_123.tmp" in message and "1 more" in message
        assert names(tmp_path) == sorted(keep + ["d"])
        assert (target / "f.txt").read_text() == "new"
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # nothing left to say the second time
            write_dir(target, "again")
    finally:
        live.stdin.close()
        live.wait(timeout=30)


def test_leftovers_of_a_file_are_removed(tmp_path):
    (tmp_path / f".a.txt.{dead_pid()}.k3j4h5g6.tmp").write_text("half")
    with pytest.warns(LeftoverWarning, match="a.txt: cleaned up"):
        atomic_write_text(tmp_path / "a.txt", "whole")
    assert names(tmp_path) == ["a.txt"]


def test_an_interrupted_replacement_is_undone_first(tmp_path):
    """A kill between the fallback's two renames leaves only ``.d.old``: the next run puts it back
    before anything else, so a failing next run still leaves the old folder."""
    target = tmp_path / "d"
    old = tmp_path / ".d.old"
    old.mkdir()
    (old / "f.txt").write_text("old")
    with pytest.warns(LeftoverWarning, match=r"\.d\.old restored as d"):
        with pytest.raises(RuntimeError):
            with atomic_dir(target) as tmp:
                assert (target / "f.txt").read_text() == "old"
                (tmp / "f.txt").write_text("half")
                raise RuntimeError
    assert names(tmp_path) == ["d"] and (target / "f.txt").read_text() == "old"
    old.mkdir()  # a stale .d.old beside a complete d: removed
    with pytest.warns(LeftoverWarning, match=r"\.d\.old"):
        write_dir(target, "new")
    assert names(tmp_path) == ["d"] and (target / "f.txt").read_text() == "new"


# ------------------------------------------------------------------ the CLI


@pytest.fixture(scope="module")
def observations(tiny_rec, tmp_path_factory) -> Path:
    from egograph.cli import main

    obs = tmp_path_factory.mktemp("lock_obs") / "obs.npz"
    assert main(["lift", str(tiny_rec), "--detections", "mvpe", "--out", str(obs), "--quiet"]) == 0
    return obs


def track_argv(rec: Path, obs: Path, out: Path, *extra: str) -> list[str]:
    return ["track", str(rec), "--tracker", "graph", "--observations", str(obs), "--out", str(out), "--quiet",
            *extra]


@pytest.mark.slow
def test_a_run_on_an_output_being_written_exits_2(tiny_rec, observations, tmp_path, capsys, monkeypatch):
    from egograph.cli import main

    out = tmp_path / "RESULTS"
    with held_elsewhere(out) as holder:
        capsys.readouterr()
        assert main(track_argv(tiny_rec, observations, out)) == 2
        err = capsys.readouterr().err
        assert err == f"egograph: error: {out}: {BUSY.format(holder.pid)}\n"
        assert not out.exists()
        monkeypatch.setenv(WAIT_ENV, "60")
        threading.Timer(0.5, release, [holder]).start()
        assert main(track_argv(tiny_rec, observations, out)) == 0
    assert (out / "intervals.json").is_file() and names(tmp_path) == ["RESULTS"]


CLI = [sys.executable, "-c", "from egograph.cli import main; import sys; sys.exit(main(sys.argv[1:]))"]


@pytest.mark.slow
def test_two_concurrent_runs_leave_one_complete_result(tiny_rec, observations, tmp_path):
    """Two ``track`` runs (other configurations) on one --out at once: each either succeeds or exits
    2 with the one-line message, and the folder is one run's complete result."""
    from egograph.cli import main

    refs = {}
    for name, extra in (("a", ["--set", "graph.covariance_floor_m=0.05"]), ("b", [])):
        ref = tmp_path / f"ref_{name}"
        with contextlib.redirect_stdout(io.StringIO()):
            assert main(track_argv(tiny_rec, observations, ref, *extra)) == 0
        refs[name] = {p.name: p.read_bytes() for p in ref.iterdir() if p.name != "egograph.json"}
    out = tmp_path / "shared" / "RESULTS"
    procs = [subprocess.Popen(CLI + track_argv(tiny_rec, observations, out, *extra), stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True)
             for extra in (["--set", "graph.covariance_floor_m=0.05"], [])]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    for rc, err in results:
        assert rc == 0 or (rc == 2 and err.startswith(f"egograph: error: {out}: another egograph run is writing "
                                                      "this output (pid ") and err.count("\n") == 1), err
    assert any(rc == 0 for rc, _ in results)
    got = {p.name: p.read_bytes() for p in out.iterdir() if p.name != "egograph.json"}
    assert got in refs.values()
    assert names(out.parent) == ["RESULTS"]
