"""What a cached or recorded result was made with: the code it ran and the package versions.

A cache that checks only hand-bumped revisions and configs goes stale silently when the code or a
dependency changes under it (stop 51: a rebuilt environment moved benchmark baselines by up to 0.7
points with no revision bumped). :func:`code_digest` fingerprints the egograph modules an entry
point reaches (its static import closure, comments and docstrings ignored) together with the
versions of the third-party distributions those modules import, so that a cache keyed by it
rebuilds exactly when something it was made with changed.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import platform
import sys
from importlib import metadata
from pathlib import Path
from typing import Iterable

PACKAGE = "egograph"
DISPLAY_ONLY = frozenset({"tqdm", "rich"})
"""Third-party modules that only draw progress and tables: their versions never change a result."""


_ROOT = Path(__file__).resolve().parents[1]  # the egograph package folder


def _source_path(module: str, root: Path = _ROOT) -> Path | None:
    """The source file of an egograph module, found on disk under the package folder ``root`` (nothing
    is imported), or None when ``module`` names no module (``name`` in ``from egograph.x import name``)."""
    parts = module.split(".")[1:]
    base = root.joinpath(*parts)
    for path in (base / "__init__.py", base.with_suffix(".py") if parts else None):
        if path is not None and path.is_file():
            return path
    return None


def _imports(tree: ast.AST, module: str, is_package: bool) -> set[str]:
    """Absolute names imported anywhere in ``tree`` (module level and inside functions)."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the importing module's package
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.add(name)
            # "from egograph.synth import scene" imports a module, not a name
            out.update(f"{name}.{a.name}" for a in node.names if a.name != "*")
    return out


def _strip_docstrings(tree: ast.AST) -> ast.AST:
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return tree


def _closure(entries: tuple[str, ...], root: Path = _ROOT) -> tuple[tuple[tuple[str, str], ...], tuple[str, ...]]:
    """``((module, normalised AST digest), ...), (third-party top-level names, ...)`` of the egograph
    modules reachable from ``entries`` by static imports, both sorted."""
    seen: dict[str, str] = {}
    third: set[str] = set()
    todo = list(entries)
    while todo:
        mod = todo.pop()
        if mod in seen:
            continue
        path = _source_path(mod, root)
        if path is None:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        names = _imports(tree, mod, path.name == "__init__.py")
        seen[mod] = hashlib.sha256(ast.dump(_strip_docstrings(tree)).encode()).hexdigest()
        for name in sorted(names):
            top = name.split(".")[0]
            if top == PACKAGE:
                # a submodule named in "from pkg import name" when it is one; its parent packages too
                parts = name.split(".")
                for i in range(1, len(parts) + 1):
                    sub = ".".join(parts[:i])
                    if sub not in seen and _source_path(sub, root) is not None:
                        todo.append(sub)
            elif top and top not in sys.stdlib_module_names and top not in DISPLAY_ONLY and top != "__future__":
                third.add(top)
    return tuple(sorted(seen.items())), tuple(sorted(third))


@functools.lru_cache(maxsize=1)
def _distributions() -> dict:
    return metadata.packages_distributions()


def package_versions(import_names: Iterable[str]) -> dict[str, str]:
    """``{distribution: version}`` of the installed distributions that provide the top-level import
    names (``cv2`` -> opencv-contrib-python-headless), plus ``python``; a name no installed
    distribution provides is left out."""
    provides = _distributions()
    out = {"python": platform.python_version()}
    for name in import_names:
        for dist in provides.get(name, []):
            try:
                out[dist] = metadata.version(dist)
            except metadata.PackageNotFoundError:  # a stale mapping entry
                continue
    return dict(sorted(out.items()))


def code_digest(*entries: str, exclude: Iterable[str] = (), root: Path = _ROOT) -> dict:
    """Fingerprint of what the modules ``entries`` (``"egograph.synth.generate"``) compute with:
    ``{"modules": 16-hex digest of every egograph module they reach, "packages": {distribution:
    version} of the third-party ones those import, "python"}``. Comments, docstrings and formatting
    do not change it; any other edit to a reached module, or another version of a reached
    distribution, does. Modules in ``exclude`` are followed but left out of the digest (a part
    fingerprinted on its own: the benchmark set re-simulates detections, not the whole recording,
    when only ``egograph.synth.frontend`` changed). ``root``: the egograph package folder (tests)."""
    mods, third = _closure(tuple(sorted(entries)), Path(root))
    skip = set(exclude)
    h = hashlib.sha256("\n".join(f"{m} {d}" for m, d in mods if m not in skip).encode())
    return {"modules": h.hexdigest()[:16], "packages": package_versions(third)}


def describe_change(before: dict | None, now: dict) -> str:
    """What differs between two :func:`code_digest` values, in words (for the message of a rebuild)."""
    if not before:
        return "made before code digests were recorded"
    out = []
    if before.get("modules") != now.get("modules"):
        out.append("egograph code changed")
    old, new = before.get("packages", {}), now.get("packages", {})
    out += [f"{k} {old.get(k, 'absent')} -> {new.get(k, 'absent')}" for k in sorted(set(old) | set(new))
            if old.get(k) != new.get(k)]
    return ", ".join(out) or "unchanged"
