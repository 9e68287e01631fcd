"""Benchmarks as data: tools/benchdoc.py records what a benchmark prints, tools/bench_report.py
renders docs/benchmarks.md from the records, and the committed page is what the committed records
render."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))

import bench_report  # noqa: E402
import benchdoc  # noqa: E402


def test_committed_benchmarks_page_is_what_the_records_render():
    """docs/benchmarks.md equals tools/bench_report.py's rendering of docs/bench/*.json, byte for byte
    (run `.venv/bin/python tools/bench_report.py` after adding a record)."""
    page = REPO / "docs" / "benchmarks.md"
    assert page.is_file(), "docs/benchmarks.md is missing: run tools/bench_report.py"
    assert bench_report.main(["--check"]) == 0, "docs/benchmarks.md is stale: run .venv/bin/python tools/bench_report.py"
    bench = REPO / "docs" / "bench"
    regens = bench_report.load_regenerations(bench)
    assert page.read_text() == bench_report.render(bench_report.load(bench), regens=regens)


def test_every_section_has_a_record():
    """No section of docs/benchmarks.md says 'Not yet regenerated': each has a record in docs/bench/
    (`tools/bench_report.py --regenerate --tier quick` makes the missing ones)."""
    docs = bench_report.load(REPO / "docs" / "bench")
    missing = [s.stem for s in bench_report.SECTIONS if s.stem not in docs]
    assert not missing, f"sections without a record: {missing}"


def test_every_section_has_a_quick_tier_with_its_sizes_and_modules():
    for s in bench_report.SECTIONS:
        tool = f"tools/{s.tool}.py"
        assert tool in s.quick and s.quick != s.command, s.stem
        tag = s.stem.split("-", 1)[1] if "-" in s.stem else None
        assert (f"--json-tag {tag}" in s.quick) == (tag is not None), (s.stem, s.quick)
        assert s.size("quick") and s.size("full") and s.size("quick") != s.size("full"), s.stem
        assert s.paths()[0] == tool and s.modules, s.stem
        for m in s.paths():
            assert (REPO / m).exists(), (s.stem, m)
        assert all(a in {x.stem for x in bench_report.SECTIONS} for a in s.after), s.stem
    order = [s.stem for s in bench_report.select(None)]
    assert len(order) == len(bench_report.SECTIONS)
    for s in bench_report.SECTIONS:   # a section runs after the one whose outputs it reads
        assert all(order.index(a) < order.index(s.stem) for a in s.after), s.stem


def test_every_record_is_named_by_a_section_and_every_section_names_a_tool():
    stems = {s.stem for s in bench_report.SECTIONS}
    assert len(stems) == len(bench_report.SECTIONS), "two sections share a record"
    for s in bench_report.SECTIONS:
        tool = s.stem.split("-", 1)[0]
        assert (REPO / "tools" / f"{tool}.py").is_file(), s.stem
        assert f"tools/{tool}.py" in s.command, (s.stem, s.command)
        tag = s.stem.split("-", 1)[1] if "-" in s.stem else None
        assert (f"--json-tag {tag}" in s.command) == (tag is not None), (s.stem, s.command)
    for p in sorted((REPO / "docs" / "bench").glob("*.json")):
        assert p.stem in stems, f"{p.name}: no section of tools/bench_report.py names this record"


def test_sections_name_the_world_their_record_was_made_in():
    """A tool that builds its benchmark set in a generator world (--world, default device since issue
    38) is given the world of its record in both tiers: a record without the argument was made in the
    legacy world."""
    import re

    docs = bench_report.load(REPO / "docs" / "bench")
    for s in bench_report.SECTIONS:
        source = (REPO / "tools" / f"{s.tool}.py").read_text()
        if "--world" not in source and "add_world_argument" not in source:
            continue
        if "--latency-only" in s.command or s.stem not in docs:   # builds no benchmark set; no record yet
            continue
        made_in = docs[s.stem].get("arguments", {}).get("world", "legacy")
        made_in = " ".join(made_in) if isinstance(made_in, list) else made_in
        for cmd in (s.command, s.quick):
            m = re.search(r"--world ((?:device|legacy)(?: (?:device|legacy))*)", cmd)
            assert m and m.group(1) == made_in, (s.stem, cmd, made_in)


def test_every_bench_tool_records_its_run():
    """Each tools/bench_*.py takes --json/--json-tag and starts and finishes a record."""
    tools = sorted((REPO / "tools").glob("bench_*.py"))
    assert len(tools) >= 11
    for p in tools:
        if p.name == "bench_report.py":
            continue
        src = p.read_text()
        for call in ("benchdoc.add_arguments(", "benchdoc.start(", "benchdoc.finish()"):
            assert call in src, f"{p.name} lacks {call}"
        assert "benchdoc.table(" in src or "heldout_table(" in src, p.name


def _record(tmp_path: Path, capsys) -> tuple[Path, str]:
    """A made-up run of a tool, written to a JSON record; returns its path and what was printed."""
    bench = benchdoc.start("tools/bench_madeup.py", {"seeds": [301, 302], "frames": 3000, "cache": Path("/x"),
                                                     "json": str(tmp_path / "bench_madeup.json")},
                           argv=["--seeds", "301", "302"])
    try:
        benchdoc.table("Made-up trackers", ["tracker", "P@0.25", "L2 (m)", "recovered", "holds", "n"],
                       [["graph", 97.456, 0.0762, [168, 209, 80.38], True, 3],
                        ["kf", float("nan"), None, [1, 2, 50.0], False, 4]],
                       ["", ".1f", ".2f", "{0}/{1} ({2:.0f} %)", "yes|NO", "d"], note="pooled over 2 recordings")
        benchdoc.text("\ngrowth 1000 -> 50000 frames: exponent 1.06\n")
        bench.data["raw"] = {"a": [1.5, float("inf")]}
    finally:
        path = benchdoc.finish()
    return path, capsys.readouterr().out


def test_a_record_round_trips_through_json_and_renders_what_was_printed(tmp_path, capsys):
    path, printed = _record(tmp_path, capsys)
    assert path == tmp_path / "bench_madeup.json"
    doc = json.loads(path.read_text())   # valid JSON: NaN and inf stored as null
    assert doc["format"] == benchdoc.FORMAT and doc["tool"] == "bench_madeup"
    assert doc["command"] == "tools/bench_madeup.py --seeds 301 302"
    assert doc["arguments"] == {"seeds": [301, 302], "frames": 3000, "cache": "/x"}
    assert doc["egograph"]["version"] and "dirty" in doc["egograph"]
    assert doc["machine"]["nproc"] >= 1 and len(doc["machine"]["load_average"]["end"]) == 3
    assert doc["wall_s"] >= 0 and doc["data"] == {"raw": {"a": [1.5, None]}}
    table, text = doc["items"]
    assert table["rows"][0] == ["graph", 97.456, 0.0762, [168, 209, 80.38], True, 3]   # numbers stay numbers
    assert table["rows"][1][1:3] == [None, None]
    assert text == {"type": "text", "text": "growth 1000 -> 50000 frames: exponent 1.06"}
    lines = benchdoc.table_lines(table)
    assert lines == ["| tracker | P@0.25 | L2 (m) | recovered | holds | n |", "|---|---|---|---|---|---|",
                     "| graph | 97.5 | 0.08 | 168/209 (80 %) | yes | 3 |", "| kf | n/a | n/a | 1/2 (50 %) | NO | 4 |"]
    for line in lines:   # what the tool printed is what the page shows
        assert line in printed.splitlines()
    page = bench_report.render({"bench_madeup": doc}, sections=(
        bench_report.Section("bench_madeup", "Made-up", "What it measures.", ".venv/bin/python tools/bench_madeup.py"),))
    body = page.split("## Made-up", 1)[1]
    assert "- command: `.venv/bin/python tools/bench_madeup.py --seeds 301 302`" in body
    assert f"commit `{doc['egograph']['commit'][:10]}`" in body if doc["egograph"]["commit"] else True
    assert f"- machine: {doc['machine']['nproc']} CPUs" in body and "wall time" in body
    assert "\n".join(lines) in body and "pooled over 2 recordings" in body and "exponent 1.06" in body
    assert page == bench_report.render({"bench_madeup": json.loads(path.read_text())}, sections=(
        bench_report.Section("bench_madeup", "Made-up", "What it measures.", ".venv/bin/python tools/bench_madeup.py"),))


def test_render_is_deterministic_and_says_what_is_missing(tmp_path, capsys):
    path, _ = _record(tmp_path, capsys)
    docs = bench_report.load(tmp_path)
    a, b = bench_report.render(docs), bench_report.render(bench_report.load(tmp_path))
    assert a == b
    # a record no section names is still shown; every section without a record gives its command
    assert "## Other recorded runs" in a and "### bench_madeup" in a
    for s in bench_report.SECTIONS:
        assert f"Not yet regenerated: run `.venv/bin/python tools/bench_report.py --regenerate --only {s.stem}`" in a
        assert f"full tier: `{s.command}`" in a and f"quick tier: `{s.quick}`" in a


def test_check_fails_with_a_diff_on_a_stale_page(tmp_path, capsys):
    _record(tmp_path, capsys)
    out = tmp_path / "benchmarks.md"
    assert bench_report.main(["--bench-dir", str(tmp_path), "--out", str(out)]) == 0
    assert bench_report.main(["--bench-dir", str(tmp_path), "--out", str(out), "--check"]) == 0
    out.write_text(out.read_text().replace("97.5", "98.1"))
    capsys.readouterr()
    assert bench_report.main(["--bench-dir", str(tmp_path), "--out", str(out), "--check"]) == 1
    diff = capsys.readouterr().out
    assert "-| graph | 98.1 |" in diff and "+| graph | 97.5 |" in diff


def test_a_file_that_is_not_a_record_is_refused_naming_it(tmp_path):
    (tmp_path / "bench_x.json").write_text('{"tool": "x"}')
    with pytest.raises(SystemExit, match="bench_x.json: not a benchmark record"):
        bench_report.load(tmp_path)


def test_cell_formats():
    f = benchdoc.format_cell
    assert f(None, ".2f") == "n/a" and f(3, "d") == "3" and f("x", ".1f") == "x" and f("-", "{0:.2f} (n={1})") == "-"
    assert f([1.234, 5.678], "{0:.1f} / {1:.1f}") == "1.2 / 5.7" and f([1, None], "{0}/{1}") == "n/a"
    assert f(0.5, ".0%") == "50%" and f(True, "YES|no") == "YES" and f(False, "YES|no") == "no"
    assert benchdoc.jsonable([float("nan"), math.inf, (1, 2)]) == [None, None, [1, 2]]
    with pytest.raises(ValueError, match="formats for"):
        benchdoc.make_table("t", ["a", "b"], [[1, 2]], ["d"])
    with pytest.raises(ValueError, match="a row of 1 cells"):
        benchdoc.make_table("t", ["a", "b"], [[1]])


def test_the_readme_score_tables_are_rendered_from_the_records():
    sys.path.insert(0, str(REPO / "tools"))
    import bench_report

    docs = bench_report.readme_docs(REPO / "docs" / "bench", bench_report.load(REPO / "docs" / "bench"))
    readme = (REPO / "README.md").read_text()
    assert bench_report.README_BEGIN in readme and bench_report.README_END in readme
    block = bench_report.readme_scores(docs)
    assert block is not None and block in readme
    # end to end from pixels first (egograph detect's own detections), the simulated detections after
    first = block.split("\n\n")[0].splitlines()
    assert first[0].startswith("| set | detections on the instance | tracker |")
    assert [r.split(" | ")[2] for r in first[2:]] == ["memory (paper's pipeline)", "**graph** (offline)"] * 4
    # the default front-end, then the verified one (the record's verify variant), per set
    assert [r.split(" | ")[0] for r in first[2::2]] == ["| SVOE", "| SVOE, verified", "| MVPE", "| MVPE, verified"]
    # a changed record changes the README block: nothing in it is typed by hand
    tampered = bench_report.with_readme_scores(readme.replace(block, "| stale |"), docs)
    assert tampered == readme
    # the README's records are the full-size ones: its own copies, with their provenance in the block
    # and whether the code they exercise changed since (a quick-tier regeneration does not refresh them)
    sections = {s.stem: s for s in bench_report.SECTIONS}
    for stem in bench_report.README_RECORDS:
        assert (REPO / "docs" / "bench" / "readme" / f"{stem}.json").is_file(), stem
        commit = docs[stem]["egograph"]["commit"][:10]
        changed = bench_report.modules_changed(sections[stem], docs[stem])
        assert f"at `{commit}`, {'**code changed since**' if changed else 'code unchanged since'}" in block
    stale = json.loads(json.dumps(docs[stem]))
    stale["regeneration"]["modules_digest"] = "0" * 16
    assert f"at `{commit}`, **code changed since**" in bench_report.readme_scores({**docs, stem: stale})


def _fake_repo(tmp_path: Path) -> Path:
    repo = tmp_path / "repo"
    (repo / "tools").mkdir(parents=True)
    (repo / "pkg").mkdir()
    (repo / "tools" / "bench_madeup.py").write_text("print(1)\n")
    (repo / "pkg" / "a.py").write_text("x = 1\n")
    (repo / "pkg" / "b.yaml").write_text("k: 1\n")
    return repo


def test_the_module_digest_changes_with_the_code_and_the_page_says_so(tmp_path, capsys):
    repo = _fake_repo(tmp_path)
    sec = bench_report.Section("bench_madeup", "Made-up", "What it measures.", ".venv/bin/python tools/bench_madeup.py",
                               quick=".venv/bin/python tools/bench_madeup.py --quick",
                               sizes=(("quick", "1 x 10 frames"), ("full", "9 x 90 frames")), modules=("pkg",))
    d0 = bench_report.modules_digest(sec.paths(), repo)
    assert d0 == bench_report.modules_digest(sec.paths(), repo) and len(d0) == 16
    path, _ = _record(tmp_path, capsys)
    doc = json.loads(path.read_text())
    doc["regeneration"] = {"tier": "quick", "sizes": sec.size("quick"), "modules": list(sec.paths()),
                           "modules_digest": d0, "digest_scheme": bench_report.DIGEST_SCHEME}
    assert bench_report.modules_changed(sec, doc, repo) is False
    assert bench_report.is_current(sec, doc, "quick", repo) and not bench_report.is_current(sec, doc, "full", repo)
    page = bench_report.render({"bench_madeup": doc}, (sec,), repo=repo)
    assert "- tier: quick (1 x 10 frames)" in page and "unchanged since" in page and "| quick |" in page
    (repo / "pkg" / "a.py").write_text("x = 2\n")   # the code the section exercises changes
    assert bench_report.modules_digest(sec.paths(), repo) != d0
    assert bench_report.modules_changed(sec, doc, repo) is True
    assert not bench_report.is_current(sec, doc, "quick", repo)
    page = bench_report.render({"bench_madeup": doc}, (sec,), repo=repo)
    assert "**changed since**: re-run `tools/bench_report.py --regenerate --only bench_madeup`" in page
    (repo / "pkg" / "a.py").write_text("x = 1\n")
    (repo / "pkg" / "__pycache__").mkdir()
    (repo / "pkg" / "__pycache__" / "a.pyc").write_bytes(b"compiled")   # not code the digest covers
    assert bench_report.modules_digest(sec.paths(), repo) == d0
    del doc["regeneration"]   # a record made by hand keeps no digest
    assert bench_report.modules_changed(sec, doc, repo) is None
    page = bench_report.render({"bench_madeup": doc}, (sec,), repo=repo)
    assert "whether its code changed since is not known" in page


def _config_repo(tmp_path: Path, default_yaml: str) -> tuple[Path, Path]:
    """A repository with a made-up tool and a packaged ``egograph/configs/default.yaml``: (root, that file)."""
    repo = tmp_path / "repo"
    (repo / "tools").mkdir(parents=True)
    (repo / "egograph" / "configs").mkdir(parents=True)
    (repo / "tools" / "bench_madeup.py").write_text("print(1)\n")
    cfg = repo / "egograph" / "configs" / "default.yaml"
    cfg.write_text(default_yaml)
    return repo, cfg


def test_a_front_end_default_does_not_mark_the_tracker_sections_changed(tmp_path):
    """A packaged config counts by what a section's code can read: the ``frontend`` block only for
    sections that exercise egograph/frontend, comments for none; any other key for every section."""
    repo, cfg = _config_repo(tmp_path, "# defaults\ngraph:\n  min_observations: 4\nfrontend:\n  proposals: geometry+image\n")
    tracker = ("tools/bench_madeup.py", "egograph/configs")
    frontend = (*tracker, "egograph/frontend")
    t0, f0 = bench_report.modules_digest(tracker, repo), bench_report.modules_digest(frontend, repo)
    cfg.write_text("# the defaults, reworded\ngraph:\n  min_observations: 4\nfrontend:\n  proposals: geometry+image\n")
    assert (bench_report.modules_digest(tracker, repo), bench_report.modules_digest(frontend, repo)) == (t0, f0)
    cfg.write_text("graph:\n  min_observations: 4\nfrontend:\n  proposals: geometry+mesh+image\n")
    assert bench_report.modules_digest(tracker, repo) == t0
    assert bench_report.modules_digest(frontend, repo) != f0
    cfg.write_text("graph:\n  min_observations: 6\nfrontend:\n  proposals: geometry+mesh+image\n")
    assert bench_report.modules_digest(tracker, repo) != t0
    # scheme 1 (every byte) still reads as it did, for records made before scheme 2
    assert bench_report.modules_digest(tracker, repo, scheme=1) != bench_report.modules_digest(tracker, repo)


def test_a_front_end_operating_point_marks_only_the_front_end_sections_changed(tmp_path):
    """Scheme 6: a packaged front-end config (``frontend-svoe.yaml``), graph and track blocks included,
    counts only for sections that exercise egograph/frontend; default.yaml's graph block for all."""
    repo, cfg = _config_repo(tmp_path, "graph:\n  min_observations: 4\n")
    op = cfg.parent / "frontend-svoe.yaml"
    op.write_text("frontend:\n  verify_threshold: 0.3\ngraph:\n  score_threshold: 0.3\n")
    tracker = ("tools/bench_madeup.py", "egograph/configs")
    frontend = (*tracker, "egograph/frontend")
    t0, f0 = bench_report.modules_digest(tracker, repo), bench_report.modules_digest(frontend, repo)
    t5 = bench_report.modules_digest(tracker, repo, scheme=5)
    op.write_text("frontend:\n  verify_threshold: 0.5\ngraph:\n  score_threshold: 0.5\n")
    assert bench_report.modules_digest(tracker, repo) == t0
    assert bench_report.modules_digest(frontend, repo) != f0
    assert bench_report.modules_digest(tracker, repo, scheme=5) != t5   # scheme 5 counted its graph block
    cfg.write_text("graph:\n  min_observations: 6\n")
    assert bench_report.modules_digest(tracker, repo) != t0
    assert bench_report.is_frontend_config("egograph/configs/frontend-mvpe.yaml")
    assert not bench_report.is_frontend_config("egograph/configs/synth/frontend-x.yaml")


def test_the_verified_rows_run_at_frontend_svoes_operating_point():
    """The device record's verified variant is, for SVOE, exactly ``--config frontend-svoe``: detector
    and trackers at the packaged threshold."""
    from egograph.core.config import load_config
    from egograph.core.resources import packaged_config_or_error
    from egograph.steps.settings import EgographConfig

    preset = load_config(EgographConfig, packaged_config_or_error("frontend-svoe"))
    sets = dict(kv.split("=") for kv in bench_report.VERIFY_SETS.split(","))
    assert sets["frontend.verify"] == "all"
    for key in ("frontend.verify_threshold", "graph.score_threshold", "track.score_threshold"):
        assert float(sets[key]) == preset.frontend.verify_threshold


def test_old_digests_are_upgraded_only_where_their_commit_reproduces_them(tmp_path):
    import subprocess

    repo, cfg = _config_repo(tmp_path, "graph:\n  min_observations: 4\nfrontend:\n  proposals: geometry+image\n")
    git = ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "-A"], check=True)
    subprocess.run([*git, "commit", "-qm", "c"], check=True)
    commit = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    sec = bench_report.Section("bench_madeup", "Made-up", "What it measures.", "x", modules=("egograph/configs",))
    old = bench_report.modules_digest(sec.paths(), repo, scheme=1)
    made = lambda digest: {"egograph": {"commit": commit}, "regeneration": {  # noqa: E731
        "tier": "quick", "modules": list(sec.paths()), "modules_digest": digest}}
    cfg.write_text("graph:\n  min_observations: 4\nfrontend:\n  proposals: geometry+mesh+image\n")
    good, bad = made(old), made("0123456789abcdef")   # bad: made on code its commit does not hold
    assert bench_report.modules_changed(sec, good, repo) is True   # scheme 1: every byte counts
    assert bench_report.upgrade_digest(good, repo)
    assert good["regeneration"]["digest_scheme"] == bench_report.DIGEST_SCHEME
    assert bench_report.modules_changed(sec, good, repo) is False   # only the front-end block changed
    assert not bench_report.upgrade_digest(bad, repo) and bench_report.modules_changed(sec, bad, repo) is True
    assert not bench_report.upgrade_digest(good, repo)   # already upgraded
    cfg.write_text("graph:\n  min_observations: 6\n")
    assert bench_report.modules_changed(sec, good, repo) is True


def test_only_egograph_code_the_tool_can_import_counts(tmp_path):
    """Scheme 3: a module of egograph counts when the section's tool can import it - at the top, in a
    function, relatively, through a package's __init__, or as a subprocess named in one of the tool's
    strings - and not otherwise (a module named only in a docstring or in egograph's own messages
    does not count); at a commit the same, read through git."""
    import subprocess

    repo, _ = _config_repo(tmp_path, "graph:\n  min_observations: 4\n")
    pkg = repo / "egograph" / "track"
    pkg.mkdir(parents=True)
    files = {"egograph/__init__.py": "", "egograph/track/__init__.py": "",
             "egograph/track/graph.py": "from .switchable import between\n",
             "egograph/track/switchable.py": "def between():\n    return 1\n",
             "egograph/track/online.py": "def run():\n    from egograph.track.kalman import step\n",
             "egograph/track/kalman.py": "step = 1\n",
             "egograph/track/unused.py": '"""Not imported: egograph.track.unused2."""\nMSG = "see egograph.track.unused2"\n',
             "egograph/track/unused2.py": "x = 1\n", "egograph/track/cli.py": "x = 1\n",
             "tools/bench_madeup.py": ('"""Runs egograph.track.unused."""\nimport egograph.track.graph\n\n\n'
                                      "def main():\n    from egograph.track import online\n\n\n"
                                      "CMD = ['python', '-c', 'from egograph.track.cli import main']\n")}
    for rel, text in files.items():
        (repo / rel).write_text(text)
    paths = ("tools/bench_madeup.py", "egograph/track")
    assert bench_report.import_closure(["tools/bench_madeup.py"], bench_report._reader(repo, None)) == {
        "tools/bench_madeup.py", "egograph/__init__.py", "egograph/track/__init__.py", "egograph/track/graph.py",
        "egograph/track/switchable.py", "egograph/track/online.py", "egograph/track/kalman.py",
        "egograph/track/cli.py"}
    d0 = bench_report.modules_digest(paths, repo)
    for name in ("unused.py", "unused2.py"):
        (pkg / name).write_text("x = 2\n")
        assert bench_report.modules_digest(paths, repo) == d0, name
    assert bench_report.modules_digest(paths, repo, scheme=2) != d0   # scheme 2 counts them
    for name in ("switchable.py", "kalman.py", "cli.py", "__init__.py"):
        before = bench_report.modules_digest(paths, repo)
        (pkg / name).write_text((pkg / name).read_text() + "CHANGED = 1\n")
        assert bench_report.modules_digest(paths, repo) != before, name
    git = ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "-A"], check=True)
    subprocess.run([*git, "commit", "-qm", "c"], check=True)
    assert bench_report.modules_digest(paths, repo, commit="HEAD") == bench_report.modules_digest(paths, repo)


def test_a_docstring_comment_or_layout_edit_changes_no_digest(tmp_path):
    """Scheme 4: a Python file counts by its syntax tree without docstrings - a docstring, a comment
    or the layout edited leaves the digest, a changed statement, constant or message changes it (also
    in the tool itself); scheme 3 counted the bytes. A file that does not parse counts by its bytes."""
    repo, _ = _config_repo(tmp_path, "graph:\n  min_observations: 4\n")
    (repo / "egograph" / "track").mkdir(parents=True)
    mod = repo / "egograph" / "track" / "graph.py"
    tool = repo / "tools" / "bench_madeup.py"
    (repo / "egograph" / "__init__.py").write_text("")
    (repo / "egograph" / "track" / "__init__.py").write_text("")
    mod.write_text('"""Graph."""\n\n\ndef solve(x):\n    """Solve."""\n    return x + 1  # why\n')
    tool.write_text("import egograph.track.graph\n")
    paths = ("tools/bench_madeup.py", "egograph/track")
    d0 = bench_report.modules_digest(paths, repo)
    s3 = bench_report.modules_digest(paths, repo, scheme=3)
    mod.write_text('"""Graph, with a better docstring."""\n\n\ndef solve(x):\n    """Solve it: x + 1, '
                   'metres."""\n    # a comment of its own line\n    return (x\n            + 1)  # why, said better\n')
    tool.write_text("# the benchmark\nimport egograph.track.graph  # the graph\n")
    assert bench_report.modules_digest(paths, repo) == d0
    assert bench_report.modules_digest(paths, repo, scheme=3) != s3
    for text in ('def solve(x):\n    return x + 2\n', 'def solve(x):\n    return x + 1\n\n\nMSG = "a message"\n'):
        mod.write_text(text)
        assert bench_report.modules_digest(paths, repo) != d0, text
    mod.write_text('"""Graph."""\n\n\ndef solve(x):\n    """Solve."""\n    return x + 1  # why\n')
    assert bench_report.modules_digest(paths, repo) == d0
    tool.write_text("import egograph.track.graph\nFRAMES = 3000\n")
    assert bench_report.modules_digest(paths, repo) != d0
    assert bench_report.code_view(b"def broken(:\n") == b"def broken(:\n"
    # scheme 5: a string standing alone under a constant (an attribute docstring) is dropped too; scheme 4
    # counted it; the constant itself still counts
    tool.write_text("import egograph.track.graph\n")
    base = '"""Graph."""\n\nKINDS = ("stand", "hand")\n"""The kinds: {}."""\n\n\ndef solve(x):\n    return x + 1\n'
    mod.write_text(base.format("two"))
    d5, d4 = bench_report.modules_digest(paths, repo), bench_report.modules_digest(paths, repo, scheme=4)
    mod.write_text(base.format("two, counted on 34 recordings"))
    assert bench_report.modules_digest(paths, repo) == d5 and bench_report.modules_digest(paths, repo, scheme=4) != d4
    mod.write_text(base.format("two").replace('"hand")', '"hand", "held")'))
    assert bench_report.modules_digest(paths, repo) != d5
    # a body of strings alone keeps a statement
    assert b"Pass" in bench_report.code_view(b"class A:\n    'x'\n    'y'\n")


WRITER = """import sys
sys.path.insert(0, {tools!r})
import benchdoc
out, mark = sys.argv[1], sys.argv[2]
if mark == 'fail':
    sys.exit(3)
tool = out.rsplit('/', 1)[1].split('-')[0].removesuffix('.json')
benchdoc.start('tools/' + tool + '.py', {{'json': out}}, argv=[mark])
benchdoc.table('t', ['a'], [[1]], ['d'])
benchdoc.finish()
"""


@pytest.fixture
def regen(tmp_path, monkeypatch):
    """A scratch regeneration: (records folder, page, the WRITER script, the file each section's command
    appends its stem to); section logs under tmp_path/logs."""
    bench_dir = tmp_path / "bench"
    bench_dir.mkdir()
    writer = tmp_path / "writer.py"
    writer.write_text(WRITER.format(tools=str(REPO / "tools")))
    monkeypatch.setattr(bench_report, "LOG_DIR", tmp_path / "logs")
    return bench_dir, tmp_path / "benchmarks.md", writer, tmp_path / "calls.txt"


def test_a_killed_regeneration_resumes_without_running_finished_sections_again(regen):
    bench_dir, out, writer, calls = regen

    def sections(second: str) -> tuple:
        def cmd(stem, mark):   # appends its stem to calls.txt, then writes the record (or fails)
            return f"echo {stem} >> {calls} && {sys.executable} {writer} {bench_dir / (stem + '.json')} {mark}"
        mods = ("tests/test_bench_report.py",)
        return (bench_report.Section("bench_aa", "A", "a.", cmd("bench_aa", "full"), quick=cmd("bench_aa", "quick"),
                                     sizes=(("quick", "small"), ("full", "big")), modules=mods, quick_min=1),
                bench_report.Section("bench_bb", "B", "b.", cmd("bench_bb", "full"), quick=cmd("bench_bb", second),
                                     sizes=(("quick", "small"), ("full", "big")), modules=mods, quick_min=2,
                                     after=("bench_aa",)))

    # the first run stops at the second section (as a kill would): its record is missing
    assert bench_report.regenerate("quick", None, 1, None, bench_dir, out, sections=sections("fail")) == 1
    assert calls.read_text().split() == ["bench_aa", "bench_bb"]
    docs = bench_report.load(bench_dir)
    assert list(docs) == ["bench_aa"] and docs["bench_aa"]["regeneration"]["tier"] == "quick"
    assert docs["bench_aa"]["argv"] == ["quick"]
    # resumed: the finished section is kept, only the other runs
    assert bench_report.regenerate("quick", None, 1, None, bench_dir, out, sections=sections("quick")) == 0
    assert calls.read_text().split() == ["bench_aa", "bench_bb", "bench_bb"]
    log = json.loads((bench_dir / "regeneration" / "quick.json").read_text())
    assert len(log["invocations"]) == 2 and log["complete"]
    assert log["invocations"][1]["sections"] == {"bench_bb": log["invocations"][1]["sections"]["bench_bb"]}
    page = out.read_text()
    assert "**Last quick-tier regeneration**" in page and "in 2 invocations (killed or stopped, then resumed)" in page
    assert "; the last invocation ran 1 section in " in page and ", 1 at a time" in page
    assert page.count("- tier: quick (small)") == 2
    # everything current: nothing runs; the full tier runs both again
    assert bench_report.regenerate("quick", None, 1, None, bench_dir, out, sections=sections("quick")) == 0
    assert calls.read_text().split() == ["bench_aa", "bench_bb", "bench_bb"]
    assert bench_report.regenerate("full", ["bench_bb"], 1, None, bench_dir, out, sections=sections("quick")) == 0
    assert calls.read_text().split()[-1] == "bench_bb" and bench_report.load(bench_dir)["bench_bb"]["argv"] == ["full"]


def test_a_section_that_lost_an_output_lock_runs_again_after_the_holder(tmp_path, regen):
    # two sections generating one benchmark recording at once: the second is refused by the output lock
    bench_dir, out, writer, calls = regen
    flag = tmp_path / "generated"
    refused = f"echo 'error: {bench_report.LOCK_MESSAGE} (pid 1); wait for it or choose another --out' && exit 2"

    def write(stem):
        return f"{sys.executable} {writer} {bench_dir / (stem + '.json')} quick"
    mods = ("tests/test_bench_report.py",)
    holder = f"echo bench_aa >> {calls} && sleep 2 && touch {flag} && " + write("bench_aa")
    waiter = f"echo bench_bb >> {calls} && if test -e {flag}; then {write('bench_bb')}; else {refused}; fi"
    always = f"echo bench_cc >> {calls} && {refused}"
    other = f"echo bench_dd >> {calls} && exit 3"
    sections = tuple(bench_report.Section(stem, stem, ".", cmd, modules=mods, quick_min=1)
                     for stem, cmd in (("bench_aa", holder), ("bench_bb", waiter), ("bench_cc", always),
                                       ("bench_dd", other)))
    assert bench_report.regenerate("quick", None, 2, None, bench_dir, out, sections=sections) == 1
    ran = calls.read_text().split()
    # refused once: run again, and it waited for the holder; refused twice: failed; any other error: not again
    assert sorted(ran) == ["bench_aa", "bench_bb", "bench_bb", "bench_cc", "bench_cc", "bench_dd"]
    assert len(ran) - 1 - ran[::-1].index("bench_bb") > ran.index("bench_aa")   # (its record: after the holder's)
    assert sorted(bench_report.load(bench_dir)) == ["bench_aa", "bench_bb"]
    log = json.loads((bench_dir / "regeneration" / "quick.json").read_text())
    runs = log["invocations"][-1]["sections"]
    assert runs["bench_bb"]["status"] == "ok" and runs["bench_bb"]["attempt"] == 2
    assert runs["bench_cc"]["status"] == "failed" and runs["bench_cc"]["attempt"] == 2
    assert runs["bench_dd"]["status"] == "failed" and "attempt" not in runs["bench_dd"]
    assert not bench_report.lost_output_lock(bench_report.section_log("bench_dd"))
    assert not bench_report.lost_output_lock(tmp_path / "no such log")


def test_the_header_gives_the_last_invocation_that_ran_the_whole_tier():
    def inv(started, statuses, wall, commit):
        return {"started": started, "commit": commit, "slots": 2, "wall_s": wall,
                "load_average": {"start": [0.5], "end": [1.5]},
                "sections": {f"bench_{k}": {"status": st} for k, st in enumerate(statuses)}}
    log = {"complete": False, "invocations": [inv("2026-01-01T00:00:00", ["ok", "ok", "ok"], 1800.0, "a" * 40),
                                              inv("2026-01-02T00:00:00", ["ok", "failed", "ok"], 900.0, "b" * 40),
                                              inv("2026-01-03T00:00:00", ["ok"], 12.0, "c" * 40)]}
    text = " ".join(bench_report.regeneration_header({"quick": log}, 3))
    # the last whole run that failed nothing, not the log's sum over days nor a run of one section
    assert "Every section of the tier in one invocation, last: 30 min 0 s, 2 at a time" in text
    assert "started 2026-01-01T00:00:00 at `aaaaaaaaaa`, load average 0.5 at the start." in text
    assert "not complete" in text   # the log's own flag, when nothing says the records are current
    assert "not complete" not in " ".join(bench_report.regeneration_header({"quick": log}, 3, {"quick": True}))
    assert "in one invocation" not in " ".join(bench_report.regeneration_header({"quick": log}, 4))


def test_a_section_alone_runs_first_the_section_whose_missing_outputs_it_reads(tmp_path, regen):
    # a fresh checkout: the records came with the repository, the poses a section reads did not
    bench_dir, out, writer, calls = regen
    made = tmp_path / "refined"

    def cmd(stem, make=""):
        return (f"echo {stem} >> {calls} && {make}{sys.executable} {writer} {bench_dir / (stem + '.json')} quick")
    mods = ("tests/test_bench_report.py",)
    sections = (bench_report.Section("bench_aa", "A", "a.", cmd("bench_aa", f"mkdir -p {made} && "), modules=mods,
                                     quick_min=1, outputs=(("quick", str(made)),)),
                bench_report.Section("bench_bb", "B", "b.", f"test -d {made} && " + cmd("bench_bb"), modules=mods,
                                     quick_min=2, after=("bench_aa",)),
                bench_report.Section("bench_cc", "C", "c.", cmd("bench_cc"), modules=mods, quick_min=3))
    assert [s.stem for s in bench_report.select(["bench_bb"], sections)] == ["bench_aa", "bench_bb"]
    assert bench_report.regenerate("quick", None, 1, None, bench_dir, out, sections=sections) == 0
    assert calls.read_text().split() == ["bench_aa", "bench_bb", "bench_cc"]
    # outputs there: forcing one section runs that one alone
    assert bench_report.regenerate("quick", ["bench_bb"], 1, None, bench_dir, out, force=True, sections=sections) == 0
    assert calls.read_text().split()[3:] == ["bench_bb"]
    # outputs gone: the section they come from runs again first, though its record is current
    made.rmdir()
    assert bench_report.regenerate("quick", ["bench_bb"], 1, None, bench_dir, out, force=True, sections=sections) == 0
    assert calls.read_text().split()[4:] == ["bench_aa", "bench_bb"] and made.is_dir()
    made.rmdir()
    assert bench_report.regenerate("quick", ["bench_aa"], 1, None, bench_dir, out, sections=sections) == 0
    assert calls.read_text().split()[6:] == ["bench_aa"]


def test_longest_first_orders_by_the_last_measured_wall_time(tmp_path):
    regen = tmp_path / bench_report.REGEN_DIR_NAME
    regen.mkdir()
    log = {"format": bench_report.REGEN_FORMAT, "tier": "full", "complete": False, "invocations": [
        {"sections": {"a": {"status": "ok", "wall_s": 10.0}, "b": {"status": "ok", "wall_s": 900.0}}},
        {"sections": {"a": {"status": "ok", "wall_s": 1200.0}, "b": {"status": "failed", "wall_s": 1.0}}}]}
    (regen / "full.json").write_text(json.dumps(log))
    measured = bench_report.last_wall_s(tmp_path, "full")
    assert measured == {"a": 1200.0, "b": 900.0}   # the last successful run of each; a failed one does not count
    mk = lambda stem, quick_min: bench_report.Section(stem, stem, "", f"tools/{stem}.py", quick_min=quick_min)
    todo = [mk("c", 5.0), mk("b", 1.0), mk("a", 1.0), mk("d", 30.0)]
    # unmeasured sections by their quick-tier estimate (d: 30 min), measured ones by their wall time
    assert [s.stem for s in bench_report.longest_first(todo, measured)] == ["d", "a", "b", "c"]


def test_a_record_says_whether_it_was_made_with_the_pinned_versions(tmp_path):
    pins_file = tmp_path / "constraints.txt"
    pins_file.write_text("# header\nnumpy==2.4.6\nPyYAML==6.0.4  # a comment\nopencv_contrib_python_headless==5.1\n")
    pins = bench_report.pinned_versions(pins_file)
    assert pins == {"numpy": "2.4.6", "pyyaml": "6.0.4", "opencv-contrib-python-headless": "5.1"}
    same = {"packages": {"python": "3.11.7", "numpy": "2.4.6", "pyyaml": "6.0.4", "gtsam": "4.3.0"}}
    assert bench_report.packages_line(same, pins) == \
        "- packages: Python 3.11.7, as pinned in `tools/constraints.txt`"
    other = {"packages": {**same["packages"], "numpy": "2.3.0", "opencv-contrib-python-headless": "5.1"}}
    assert bench_report.packages_line(other, pins) == ("- packages: Python 3.11.7, other versions than "
                                                       "`tools/constraints.txt` pins: numpy 2.3.0 (pinned 2.4.6)")
    assert "not recorded" in bench_report.packages_line({}, pins)
    # every pinned distribution egograph requires is pinned in the committed file
    committed = bench_report.pinned_versions()
    assert {"numpy", "gtsam", "opencv-contrib-python-headless", "scipy", "onnxruntime"} <= set(committed)


def test_revision_dirty_ignores_docs_and_readme(tmp_path, monkeypatch):
    """A record is 'dirty' when code differs from the commit, not when the figures' own outputs do:
    docs/ and README.md (whose score block a running regeneration rewrites) are left out."""
    import subprocess

    def git(*args):
        subprocess.run(["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                       check=True, capture_output=True)

    (tmp_path / "docs").mkdir()
    for name in ("README.md", "docs/benchmarks.md", "code.py"):
        (tmp_path / name).write_text("a\n")
    git("init", "-q")
    git("add", ".")
    git("commit", "-q", "-m", "x")
    monkeypatch.setattr(benchdoc, "REPO", tmp_path)
    assert benchdoc.revision()["dirty"] is False
    (tmp_path / "README.md").write_text("scores\n")
    (tmp_path / "docs" / "benchmarks.md").write_text("figures\n")
    assert benchdoc.revision()["dirty"] is False
    (tmp_path / "code.py").write_text("b\n")
    assert benchdoc.revision()["dirty"] is True


def test_concurrent_regenerations_keep_each_others_sections():
    """Two regenerations of one tier running at once each save the state file: the one that saves
    last keeps the other's invocation (and its sections) instead of overwriting it."""
    a = {"started": "2026-12-05T10:00:00+00:00", "argv": ["--only", "x"], "sections": {"x": {"status": "ok"}}}
    b_old = {"started": "2026-12-05T10:05:00+00:00", "argv": ["--only", "y"], "sections": {}}
    b_new = {**b_old, "sections": {"y": {"status": "ok"}}}
    older = {"started": "2026-12-04T09:00:00+00:00", "argv": [], "sections": {}}
    # process A started before B saved anything; B has since saved y: A's save keeps it
    on_disk = {"format": bench_report.REGEN_FORMAT, "tier": "full", "invocations": [older, a, b_new]}
    got = bench_report.merged_invocations(on_disk, [older, a], a)
    assert [i["started"] for i in got] == [older["started"], a["started"], b_old["started"]]
    assert got[2]["sections"] == {"y": {"status": "ok"}}
    # two invocations started in the same second with the same arguments stay two
    c1 = {"id": "1-1", "started": a["started"], "argv": a["argv"], "sections": {"x": {"status": "failed"}}}
    c2 = {"id": "1-2", "started": a["started"], "argv": a["argv"], "sections": {}}
    disk2 = {"format": bench_report.REGEN_FORMAT, "tier": "full", "invocations": [c1]}
    assert len(bench_report.merged_invocations(disk2, [c1, c2], c2)) == 2
    # this process's own invocation is saved as it is now, not as the disk had it
    a_now = {**a, "sections": {"x": {"status": "ok"}, "z": {"status": "failed"}}}
    got = bench_report.merged_invocations(on_disk, [older, a_now], a_now)
    assert got[1]["sections"] == a_now["sections"]
    # A read B's invocation at an earlier save, before B finished; B has saved its sections since:
    # A's next save keeps B's, not its own stale copy (stop 71: a 47-minute section logged as empty)
    got = bench_report.merged_invocations(on_disk, [older, a, b_old], a)
    assert got[2]["sections"] == {"y": {"status": "ok"}}
    # an invocation the disk no longer has (the file replaced meanwhile) is kept from memory
    disk3 = {"format": bench_report.REGEN_FORMAT, "tier": "full", "invocations": [a]}
    assert [i["started"] for i in bench_report.merged_invocations(disk3, [older, a, b_new], a)] == \
        [older["started"], a["started"], b_old["started"]]
