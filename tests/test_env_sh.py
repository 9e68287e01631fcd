"""tools/env.sh (the set-up of both commands) prints one line per step, keeps what apt-get and pip
print in .venv/setup.log, and names that log, exit 1, when a step fails.

Run on a copy of the set-up files whose .venv/bin/python is a stand-in, so nothing is installed."""

from __future__ import annotations

import glob
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _system_libraries_present() -> bool:
    """env.sh would call apt-get otherwise; these tests must not."""
    libs = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout
    swrast = glob.glob("/usr/lib/*/dri/swrast_dri.so") + glob.glob("/usr/lib/dri/swrast_dri.so")
    return "libusb-1.0.so.0" in libs and "libEGL.so.1" in libs and bool(swrast)


pytestmark = pytest.mark.skipif(not _system_libraries_present(), reason="env.sh would install system packages")


def _checkout(tmp_path: Path, python: str) -> Path:
    """A checkout with tools/env.sh, tools/constraints.txt, setup.cfg, pyproject.toml and a .venv whose python is ``python``
    (a shell script)."""
    repo = tmp_path / "repo"
    (repo / "tools").mkdir(parents=True)
    for f in ("env.sh", "constraints.txt"):
        shutil.copy(REPO / "tools" / f, repo / "tools" / f)
    for f in ("setup.cfg", "pyproject.toml"):
        shutil.copy(REPO / f, repo / f)
    py = repo / ".venv" / "bin" / "python"
    py.parent.mkdir(parents=True)
    py.write_text("#!/bin/sh\n" + python)
    py.chmod(0o755)
    return repo


def _source(repo: Path) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", f'source "{repo}/tools/env.sh" && echo "PATH=$PATH"'], capture_output=True,
                          text=True, timeout=120)


def test_a_failing_step_names_the_log_and_exits_1(tmp_path):
    # a python that cannot import egograph (so env.sh installs) and whose pip fails, loudly
    repo = _checkout(tmp_path, 'echo "pip: ERROR: No matching distribution found for gtsam>=4.2" >&2\nexit 1\n')
    p = _source(repo)
    assert p.returncode == 1
    log = repo / ".venv" / "setup.log"
    assert p.stderr.splitlines() == ["set-up: upgrading pip",
                                     f"set-up failed: upgrading pip. What it printed: {log}"]
    assert p.stdout == ""
    text = log.read_text()
    assert "No matching distribution found for gtsam" in text and "upgrading pip" in text


def test_each_step_prints_one_line_and_its_output_goes_to_the_log(tmp_path):
    # a python for which every pip call succeeds with chatter; `import egograph` fails only until installed
    repo = _checkout(tmp_path, 'case "$*" in\n'
                               '  *"import egograph"*) [ -f "$(dirname "$0")/../installed" ] ;;\n'
                               '  *"pip show"*) exit 1 ;;\n'
                               '  *"pip install -c"*" -e "*) echo "Collecting gtsam ... Successfully installed 61 packages"; '
                               'touch "$(dirname "$0")/../installed" ;;\n'
                               '  *) echo "Requirement already satisfied: pip" ;;\n'
                               'esac\n')
    p = _source(repo)
    assert p.returncode == 0, p.stderr
    venv = repo / ".venv"
    assert p.stderr.splitlines() == [
        "set-up: upgrading pip",
        f"set-up: installing egograph and its dependencies into {venv} (pip; a few minutes the first time)"]
    assert f"PATH={venv}/bin:" in p.stdout
    log = (venv / "setup.log").read_text()
    assert "Successfully installed 61 packages" in log and "Requirement already satisfied" in log
    assert f"pip install -c {repo}/tools/constraints.txt -e" in log   # at the pinned versions
    # the second time nothing is installed: one line
    p = _source(repo)
    assert p.returncode == 0 and p.stderr.splitlines() == [f"set-up: {venv} is up to date"]
