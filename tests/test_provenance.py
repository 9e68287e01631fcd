"""Code digests (egograph.core.provenance): what a cache entry or a record was made with."""

from __future__ import annotations

from pathlib import Path

from egograph.core.provenance import code_digest, describe_change, package_versions


def _package(root: Path, b_source: str) -> Path:
    """A package ``egograph`` under ``root``: ``a`` imports ``b`` (inside a function) and numpy; ``c``
    is imported by nobody."""
    pkg = root / "egograph"
    (pkg / "sub").mkdir(parents=True, exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "a.py").write_text('"""A."""\nimport numpy as np\n\n\ndef f():\n    from . import b\n    return b.g()\n')
    (pkg / "sub" / "b.py").write_text(b_source)
    (pkg / "sub" / "c.py").write_text("X = 1\n")
    return pkg


def test_digest_follows_imports_and_ignores_comments_and_docstrings(tmp_path):
    pkg = _package(tmp_path, "def g():\n    return 1\n")
    first = code_digest("egograph.sub.a", root=pkg)
    assert set(first["packages"]) == {"numpy", "python"}   # a's third-party import, with its installed version
    # a comment, a docstring and blank lines in a module it reaches: the same digest
    (pkg / "sub" / "b.py").write_text('"""B: returns one."""\n\n\ndef g():  # one\n    """One."""\n    return 1\n')
    assert code_digest("egograph.sub.a", root=pkg) == first
    # a module it does not reach: the same digest
    (pkg / "sub" / "c.py").write_text("X = 2\n")
    assert code_digest("egograph.sub.a", root=pkg) == first
    # code in a module it reaches through a relative import inside a function: another digest
    (pkg / "sub" / "b.py").write_text("def g():\n    return 2\n")
    second = code_digest("egograph.sub.a", root=pkg)
    assert second["modules"] != first["modules"]
    assert describe_change(first, second) == "egograph code changed"
    # left out on request (fingerprinted on its own)
    assert code_digest("egograph.sub.a", exclude=["egograph.sub.b"], root=pkg)["modules"] == \
        code_digest("egograph.sub.a", exclude=["egograph.sub.b"], root=_package(tmp_path / "x", "Y = 3\n"))["modules"]


def test_package_versions_name_the_distribution_and_the_change():
    import numpy

    versions = package_versions(["numpy", "cv2", "no_such_module_here"])
    assert versions["numpy"] == numpy.__version__ and "python" in versions
    assert any(d.startswith("opencv") for d in versions)   # cv2 -> its distribution
    assert len(versions) == 3
    old = {"modules": "a", "packages": {**versions, "numpy": "1.0"}}
    assert describe_change(old, {"modules": "a", "packages": versions}) == f"numpy 1.0 -> {numpy.__version__}"
    assert describe_change(None, old) == "made before code digests were recorded"
