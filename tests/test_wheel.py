"""Packaging: the configs ship inside the package and resolve by name, optional dependencies name
their extra, and a plain wheel installed into a fresh venv outside the checkout runs the pipeline."""

from __future__ import annotations

import importlib.util
import os
import shutil
import site
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from egograph.core.errors import ConfigError, EgographError
from egograph.core.resources import (
    config_argument,
    default_config,
    packaged_configs,
    require,
    resolve_config,
    synth_config,
)

REPO = Path(__file__).resolve().parents[1]
PACKAGED = REPO / "egograph" / "configs"


def test_packaged_configs_are_listed():
    assert packaged_configs() == ["default", "frontend-mvpe", "frontend-svoe", "synth/device-mvpe", "synth/device-svoe",
                                  "synth/device-tiny", "synth/mvpe", "synth/svoe", "synth/tiny"]
    assert default_config() == PACKAGED / "default.yaml"
    assert synth_config("tiny") == PACKAGED / "synth" / "tiny.yaml"


@pytest.mark.parametrize("name", ["synth/tiny", "synth/tiny.yaml", "configs/synth/tiny.yaml",
                                  "egograph/configs/synth/tiny.yaml"])
def test_a_packaged_name_resolves_from_anywhere(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no configs/ folder here: the packaged file is the one found
    assert resolve_config(name) == PACKAGED / "synth" / "tiny.yaml"


def test_an_existing_file_is_taken_as_it_is(tmp_path, monkeypatch):
    own = tmp_path / "synth" / "tiny.yaml"
    own.parent.mkdir()
    own.write_text("frames: 3\n")
    monkeypatch.chdir(tmp_path)
    assert resolve_config("synth/tiny.yaml") == Path("synth/tiny.yaml")
    assert resolve_config(own) == own


def test_the_checkout_configs_link_is_the_packaged_folder():
    link = REPO / "configs"
    assert link.is_symlink() and link.resolve() == PACKAGED.resolve()


def test_a_miss_names_what_was_tried_and_lists_the_packaged_configs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError) as err:
        resolve_config("synth/huge")
    msg = str(err.value)
    assert "no file synth/huge" in msg and "no packaged config synth/huge.yaml" in msg
    assert ("default, frontend-mvpe, frontend-svoe, synth/device-mvpe, synth/device-svoe, synth/device-tiny, synth/mvpe, "
            "synth/svoe, synth/tiny") in msg and "\n" not in msg
    with pytest.raises(ConfigError, match="no packaged config"):
        synth_config("huge")
    with pytest.raises(ConfigError):
        resolve_config("../default")
    assert config_argument("synth/huge") == Path("synth/huge")  # left for load_config to report


def test_the_cli_takes_a_packaged_name(tmp_path, monkeypatch):
    from egograph.cli import build_parser

    monkeypatch.chdir(tmp_path)
    args = build_parser().parse_args(["synth", "out", "--config", "synth/tiny"])
    assert args.config == PACKAGED / "synth" / "tiny.yaml"
    assert build_parser().parse_args(["info", "rec"]).config == PACKAGED / "default.yaml"


def test_a_missing_extra_is_named():
    assert require("json", "none", "anything").dumps([]) == "[]"
    with pytest.raises(EgographError) as err:
        require("egograph_no_such_module", "colmap", "refine.colmap=true")
    assert str(err.value) == "refine.colmap=true needs egograph_no_such_module: pip install 'egograph[colmap]'"


# ------------------------------------------------------------------ the wheel

BUILD_FILES = ("setup.cfg", "pyproject.toml", "README.md")


def _can_build_here() -> bool:
    """The running interpreter has the build backend (then no download is needed)."""
    return all(importlib.util.find_spec(m) is not None for m in ("setuptools", "wheel"))


def _run(cmd: list[str], cwd: Path, env: dict) -> str:
    r = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))} -> exit {r.returncode}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r.stdout


def _dependency_dirs() -> list[str]:
    """site-packages of the running environment: the wheel's dependencies, already installed."""
    dirs = site.getsitepackages() + [sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]]
    return list(dict.fromkeys(d for d in dirs if Path(d).is_dir()))


@pytest.mark.slow
def test_the_wheel_installs_and_runs_outside_the_checkout(tmp_path):
    assert REPO not in tmp_path.parents
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}
    env["PYTHONNOUSERSITE"] = "1"

    # Build from a copy of what the wheel is made of, so no build/ is left in (or taken from) the checkout.
    src = tmp_path / "src"
    shutil.copytree(REPO / "egograph", src / "egograph", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for name in BUILD_FILES:
        shutil.copy2(REPO / name, src / name)
    isolation = ["--no-build-isolation"] if _can_build_here() else []
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", *isolation, "-w", tmp_path / "dist", src],
         tmp_path, env)
    (wheel,) = (tmp_path / "dist").glob("egograph-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"egograph/io/__init__.py", "egograph/configs/default.yaml", "egograph/configs/synth/tiny.yaml"} <= names
    packages = {p.parent for p in (REPO / "egograph").rglob("*.py")}
    for pkg in packages:
        assert f"{pkg.relative_to(REPO).as_posix()}/__init__.py" in names

    # A fresh venv; the dependencies come from this environment through a .pth of plain paths
    # (so that environment's own .pth files, such as an editable egograph finder, stay inactive).
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], tmp_path, env)
    py = venv / "bin" / "python"
    purelib = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path, env).strip())
    (purelib / "zz_egograph_test_dependencies.pth").write_text("".join(f"{d}\n" for d in _dependency_dirs()))
    _run([sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "--no-index", "-q", wheel], tmp_path, env)

    work = tmp_path / "work"
    work.mkdir()
    where = _run([py, "-c", "import egograph; print(egograph.__file__)"], work, env).strip()
    assert Path(where).parent == purelib / "egograph"

    egograph = venv / "bin" / "egograph"
    _run([egograph, "synth", "rec", "--config", "synth/tiny", "--seed", "1", "--quiet", "--frames", "60",
          "--set", "pv.rgb=false", "--set", "mvpe_photo_size=32"], work, env)
    assert "tiny_seq" in _run([egograph, "info", "rec"], work, env)
    _run([egograph, "track", "rec", "--tracker", "memory", "--detections", "svoe", "--out", "results", "--quiet"],
         work, env)
    assert "IT3DEgo evaluation" in _run([egograph, "eval", "rec", "results"], work, env)
