"""What ships inside the package (the YAML configs) and the optional dependencies behind extras.

The configs live in ``egograph/configs/`` so that a plain wheel carries them; a checkout's top-level
``configs`` is a symlink to that folder, so ``--config configs/synth/svoe.yaml`` works there as well.
"""

from __future__ import annotations

import importlib
from importlib import resources
from pathlib import Path, PurePosixPath
from types import ModuleType

from egograph.core.errors import ConfigError

CONFIG_DIR = "configs"
"""Folder of the packaged configs inside the ``egograph`` package."""

SUFFIX = ".yaml"


def _config_root() -> Path:
    """The packaged config folder on disk (wheels and editable installs are unpacked, never zipped)."""
    return Path(str(resources.files("egograph").joinpath(CONFIG_DIR)))


def packaged_configs() -> list[str]:
    """Names of the packaged configs without the suffix, sorted: ``default``, ``synth/tiny``, ..."""
    root = _config_root()
    return sorted(p.relative_to(root).with_suffix("").as_posix() for p in root.rglob(f"*{SUFFIX}") if p.is_file())


def _packaged_name(name: str) -> PurePosixPath | None:
    """``synth/tiny``, ``synth/tiny.yaml`` or ``configs/synth/tiny.yaml`` -> ``synth/tiny.yaml``
    (relative to the packaged folder); None for a name that cannot be one (empty, absolute, ``..``)."""
    rel = PurePosixPath(name.replace("\\", "/"))
    if rel.is_absolute() or ".." in rel.parts:
        return None
    if rel.parts[:2] == ("egograph", CONFIG_DIR):
        rel = PurePosixPath(*rel.parts[2:])
    elif rel.parts[:1] == (CONFIG_DIR,):
        rel = PurePosixPath(*rel.parts[1:])
    if not rel.parts:
        return None
    return rel if rel.suffix == SUFFIX else rel.with_name(rel.name + SUFFIX)


def packaged_config(name: str) -> Path | None:
    """Path of the packaged config ``name`` (any form :func:`resolve_config` accepts), or None."""
    rel = _packaged_name(name)
    if rel is None:
        return None
    path = _config_root().joinpath(*rel.parts)
    return path if path.is_file() else None


def resolve_config(arg: str | Path) -> Path:
    """The config file a ``--config`` argument means.

    An existing file is taken as it is; otherwise ``arg`` names a packaged config: ``default``,
    ``synth/tiny``, ``synth/tiny.yaml`` or ``configs/synth/tiny.yaml``. A miss raises ConfigError
    naming both places tried and listing the packaged configs.
    """
    path = Path(arg)
    if path.is_file():
        return path
    found = packaged_config(str(arg))
    if found is not None:
        return found
    rel = _packaged_name(str(arg))
    tried = f"no file {path}" + (f", no packaged config {rel}" if rel is not None else "")
    raise ConfigError(f"{arg}: config not found ({tried}); packaged configs: {', '.join(packaged_configs())}")


def config_argument(text: str) -> Path:
    """``argparse`` type of ``--config``: the resolved file, or ``text`` unchanged when nothing matches
    (loading it then reports the missing file as before)."""
    path = Path(text)
    return path if path.is_file() else packaged_config(text) or path


def packaged_config_or_error(name: str) -> Path:
    """A packaged config only (a file of that name in the working folder does not count)."""
    found = packaged_config(name)
    if found is None:
        raise ConfigError(f"{name}: no packaged config of that name; packaged configs: {', '.join(packaged_configs())}")
    return found


def default_config() -> Path:
    """The packaged pipeline config (``configs/default.yaml``)."""
    return packaged_config_or_error("default")


def synth_config(name: str) -> Path:
    """The packaged synthetic-recording config ``configs/synth/<name>.yaml`` (``svoe``, ``mvpe``, ``tiny``)."""
    return packaged_config_or_error(f"synth/{name}")


def require(module: str, extra: str, what: str) -> ModuleType:
    """Import the optional dependency ``module`` for the feature ``what`` (e.g. ``refine.colmap=true``).

    When it is not installed: ConfigError (an EgographError; one line for the CLI) naming the extra,
    e.g. ``refine.colmap=true needs pycolmap: pip install 'egograph[colmap]'``. A module that is
    installed but fails to import for another reason raises its own error.
    """
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name is None or module.split(".")[0] != exc.name.split(".")[0]:
            raise
        raise ConfigError(f"{what} needs {module}: pip install 'egograph[{extra}]'") from None
