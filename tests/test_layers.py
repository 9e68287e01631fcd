"""The package's layers import in one direction only (core -> io -> geometry -> poses | track ->
eval -> synth -> steps -> cli), with no cycle between subpackages, and the light commands stay
light: reading a configuration, ``egograph info`` and ``egograph eval`` import neither GTSAM nor Open3D."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "egograph"

LAYERS = ["core", "io", "geometry", "frontend", "poses", "track", "eval", "synth", "steps", "cli"]
"""Bottom to top. A module may import from its own layer and the ones below it. ``poses`` and
``track`` are peers in the design; ``track`` sits above ``poses`` here because joint mode
(``track/joint.py``) adds the tracker's landmarks to the pose graph, never the other way round."""


def layer_of(module: str) -> str | None:
    """``egograph.io.poses`` -> ``io``; ``egograph`` itself (version only) -> ``core``."""
    parts = module.split(".")
    if parts[0] != "egograph":
        return None
    if len(parts) == 1 or parts[1].startswith("__"):  # the package itself, egograph.__version__
        return "core"
    return parts[1]


def imports_of(source: str, module: str) -> list[tuple[int, str]]:
    """(line, imported egograph module) for every import in ``source``, at any depth (lazy
    imports inside functions count: they run too)."""
    out = []
    pkg = module.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.split(".")[0] == "egograph"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            if name.split(".")[0] == "egograph":
                if name == "egograph":  # from egograph import X: X is a subpackage
                    out += [(node.lineno, f"egograph.{a.name}") for a in node.names]
                else:
                    out.append((node.lineno, name))
    return out


def module_sources(root: Path = PACKAGE) -> dict[str, tuple[Path, str]]:
    mods = {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root.parent).with_suffix("")
        name = ".".join(rel.parts)
        if name.endswith(".__init__"):
            name = name[: -len(".__init__")]
        mods[name] = (path, path.read_text())
    return mods


def layer_violations(sources: dict[str, tuple[Path, str]]) -> list[str]:
    """Every import of a higher layer, and every module outside the known layers."""
    rank = {name: k for k, name in enumerate(LAYERS)}
    bad = []
    for module, (path, src) in sources.items():
        here = layer_of(module)
        if here not in rank:
            bad.append(f"{path}: module {module} is in no layer ({', '.join(LAYERS)})")
            continue
        for line, target in imports_of(src, module):
            there = layer_of(target)
            if there not in rank:
                bad.append(f"{path}:{line}: imports {target}, which is in no layer")
            elif rank[there] > rank[here]:
                bad.append(f"{path}:{line}: {here} imports {target} from the higher layer {there}")
    return bad


def subpackage_cycles(sources: dict[str, tuple[Path, str]]) -> list[list[str]]:
    """Cycles in the graph of imports between subpackages (egograph.X -> egograph.Y, X != Y)."""
    edges: dict[str, set[str]] = {}
    for module, (_, src) in sources.items():
        a = layer_of(module)
        for _, target in imports_of(src, module):
            b = layer_of(target)
            if b and b != a:
                edges.setdefault(a, set()).add(b)
    cycles, seen = [], set()

    def walk(node, stack):
        for nxt in sorted(edges.get(node, ())):
            if nxt in stack:
                cyc = stack[stack.index(nxt):] + [nxt]
                key = frozenset(cyc)
                if key not in seen:
                    seen.add(key)
                    cycles.append(cyc)
            else:
                walk(nxt, stack + [nxt])

    for start in sorted(edges):
        walk(start, [start])
    return cycles


def test_no_upward_imports():
    assert layer_violations(module_sources()) == []


def test_no_cycles_between_subpackages():
    assert subpackage_cycles(module_sources()) == []


def test_the_checks_catch_an_upward_import_and_a_cycle():
    """The same checks on the real sources plus one planted upward import: both fire."""
    sources = dict(module_sources())
    path, src = sources["egograph.io.poses"]
    sources["egograph.io.poses"] = (path, src + "\n\ndef _late():\n    from egograph.track.graph import graph_tracker\n")
    bad = layer_violations(sources)
    assert len(bad) == 1 and "io imports egograph.track.graph from the higher layer track" in bad[0]
    assert any(set(c) >= {"io", "track"} for c in subpackage_cycles(sources))


HEAVY = ("gtsam", "open3d", "pycolmap", "kiss_icp")


def _imported_modules(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys; print(' '.join(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True)
    return set(out.stdout.split())


@pytest.mark.parametrize("code", [
    "from egograph.steps.settings import EgographConfig; EgographConfig()",
    "from egograph.cli import build_parser; build_parser()",
    "import egograph.steps.info, egograph.steps.evaluate",
])
def test_light_paths_import_no_heavy_dependency(code):
    mods = _imported_modules(code)
    assert not [m for m in HEAVY if m in mods]
