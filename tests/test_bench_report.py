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
    assert page.read_text() == bench_report.render(bench_report.load(REPO / "docs" / "bench"))


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
        assert f"Not yet regenerated: run `{s.command}`" in a


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

    docs = bench_report.load(REPO / "docs" / "bench")
    readme = (REPO / "README.md").read_text()
    assert bench_report.README_BEGIN in readme and bench_report.README_END in readme
    block = bench_report.readme_scores(docs)
    assert block is not None and block in readme
    # a changed record changes the README block: nothing in it is typed by hand
    tampered = bench_report.with_readme_scores(readme.replace(block, "| stale |"), docs)
    assert tampered == readme
