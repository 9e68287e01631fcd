"""Evaluation reports: JSON/CSV/Markdown/terminal output, the PR plot and the comparison table."""

from __future__ import annotations

import csv
import io
import json
import re

import numpy as np
import pytest
from rich.console import Console

from egograph.eval import (
    THRESHOLDS,
    EvalReport,
    GtInterval,
    comparison_table,
    evaluate_sequence,
    plot_pr,
    score_intervals,
)
from egograph.eval.loader import evaluate_loaded, load_camera_centers, load_sequence
from egograph.eval.report import (
    comparison_rich_tables,
    format_metric_cells,
    print_comparison,
    render_comparison,
    render_report,
    threshold_label,
)

K = len(THRESHOLDS)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def seq_a():
    # Frames 0, 1. Instance 0 at origin over both; exact predictions -> tp 2, n_gt 2, n_pred 2.
    # Instance 1 predicted in frame 0 without GT -> fp 1, n_pred 3.
    gt = [GtInterval(0, 0, 1, (0, 0, 0))]
    preds = {0: {0: (0, 0, 0), 1: (1, 0, 0)}, 1: {0: (0, 0, 0)}}
    return [0, 1], gt, preds


def seq_b():
    # Frames 0, 1, 2. Instance 0 at origin over all; prediction 0.6 m off in frame 0 only.
    # Frame 0: tp at τ >= 0.75, fp + fn below. Frames 1, 2: fn at every τ.
    gt = [GtInterval(0, 0, 2, (0, 0, 0))]
    preds = {0: {0: (0.6, 0, 0)}}
    return [0, 1, 2], gt, preds


def make_report(tracker_shift: float = 0.0) -> EvalReport:
    rep = EvalReport()
    for name, (ts, gt, preds), labels in (("seq_a", seq_a(), ["cup_1", "cup_2"]), ("seq_b", seq_b(), None)):
        if tracker_shift:
            preds = {t: {i: np.asarray(p) + tracker_shift for i, p in f.items()} for t, f in preds.items()}
        res = evaluate_sequence(ts, gt, preds, camera_centers=np.full((len(ts), 3), -1.0))
        rep.add(name, res, score_intervals(gt, [(0, ts[0], ts[-1], (0, 0, 0))], ts), labels=labels)
    return rep


def test_totals_sum_counts_over_sequences():
    rep = make_report()
    t = rep.total
    # tp: seq_a 2 at every τ + seq_b [0,0,1,1,1]; n_pred 3 + 1; n_gt 2 + 3.
    assert t.tp.tolist() == [2, 2, 3, 3, 3]
    assert t.fp.tolist() == [1 + 1, 1 + 1, 1, 1, 1]
    assert t.fn.tolist() == [0 + 3, 0 + 3, 2, 2, 2]
    assert (t.n_pred, t.n_gt) == (4, 5)
    assert t.precision.tolist() == pytest.approx([0.5, 0.5, 0.75, 0.75, 0.75])
    assert t.recall.tolist() == pytest.approx([0.4, 0.4, 0.6, 0.6, 0.6])
    # L2 over (frame, GT) pairs with a prediction: 0, 0, 0.6 -> 0.2 m.
    assert t.l2_m == pytest.approx(0.2)


def test_json_keys_and_round_trip(tmp_path):
    rep = make_report()
    d = rep.to_json_dict()
    for key in ("thresholds", "precision", "recall", "l2_m", "angle_rad", "pcl_0.3", "n_gt", "n_pred",
                "tp", "fp", "fn", "intervals", "per_sequence", "per_instance"):
        assert key in d, key
    assert d["thresholds"] == list(THRESHOLDS)
    assert len(d["precision"]) == len(d["recall"]) == K
    assert all(0.0 <= x <= 1.0 for x in d["precision"] + d["recall"])
    assert set(d["per_sequence"]) == {"seq_a", "seq_b"}
    assert set(d["per_instance"]) == {"seq_a/0(cup_1)", "seq_a/1(cup_2)", "seq_b/0"}
    assert d["per_instance"]["seq_a/1(cup_2)"]["fp"] == [1] * K
    for metrics in list(d["per_sequence"].values()) + list(d["per_instance"].values()):
        assert {"precision", "recall", "l2_m", "angle_rad", "pcl_0.3", "tp"} <= set(metrics)
    assert {"recovered_fraction", "median_break_error_s"} <= set(d["intervals"])
    path = tmp_path / "out" / "report.json"
    rep.write_json(path)
    loaded = json.loads(path.read_text())
    assert loaded == json.loads(json.dumps(d))
    back = EvalReport.from_json_dict(loaded)
    assert back.total == rep.total
    assert back.sequences["seq_a"].result.per_instance[1] == rep.sequences["seq_a"].result.per_instance[1]


def test_csv_markdown_and_terminal(tmp_path):
    rep = make_report()
    rep.write_csv(tmp_path / "r.csv")
    rows = list(csv.DictReader(io.StringIO((tmp_path / "r.csv").read_text())))
    assert [r["scope"] for r in rows] == ["total", "sequence", "sequence", "instance", "instance", "instance"]
    assert float(rows[0]["P@0.25"]) == pytest.approx(0.5) and rows[0]["TP@1.5"] == "3"
    rep.write_markdown(tmp_path / "r.md")
    md = (tmp_path / "r.md").read_text()
    assert "| P@0.25 |" in md and "| 50.0 |" in md and "seq_a/0(cup_1)" in md
    assert "## Intervals" in md
    console = Console(record=True, width=250)
    rep.print(console=console, per_instance=True)
    text = console.export_text()
    assert "seq_b/0" in text and "50.0" in text


def empty_report() -> EvalReport:
    """One GT interval over two frames and no prediction: precision, L2 and angle are undefined."""
    rep = EvalReport()
    rep.add("empty", evaluate_sequence([0, 1], [GtInterval(0, 0, 1, (0, 0, 0))], {}))
    return rep


def test_undefined_values_print_as_na():
    rep = empty_report()
    d = rep.to_json_dict()  # JSON keeps the protocol's 0.0 with the counts that say it is undefined
    assert d["precision"] == [0.0] * K and d["n_pred"] == 0
    assert d["l2_m"] == 0.0 and d["l2_n"] == 0
    assert d["intervals"] is None
    md = rep.to_markdown()
    assert "| total | all | n/a | n/a | n/a | n/a | n/a | 0.0 | 0.0 | 0.0 | 0.0 | 0.0 | n/a | n/a | 0.0 | 2 | 0 |" in md
    assert "(n=0)" not in md
    row = list(csv.DictReader(io.StringIO(rep.to_csv())))[0]
    assert row["P@0.25"] == "" and row["l2_m"] == "" and row["angle_rad"] == "" and row["R@0.25"] == "0.0"
    console = Console(width=80, record=True)
    rep.print(console=console)
    text = console.export_text()
    assert text.count("n/a") >= 7 and "0.00 " not in text.replace("0.00 s", "")
    # a NaN (e.g. from hand-built counts) is undefined too
    rep2 = make_report()
    rep2.sequences["seq_b"].result.total.l2_sum = float("nan")
    assert format_metric_cells(rep2.total)["L2 (m)"] == "n/a"


def header_names(text: str) -> set[str]:
    """Headers of right-aligned columns in a rendered table: a token of one line joined with the token
    ending at the same column on the line above (two-line headers ``P@`` / ``0.25``), spaces removed."""
    lines = text.splitlines()
    out = set()
    for above, line in zip([""] + lines, lines):
        ends = {m.end(): m.group() for m in re.finditer(r"\S+", above)}
        for m in re.finditer(r"\S+", line):
            out.add(ends.get(m.end(), "") + m.group())
    return out


def test_terminal_table_fits_80_columns_with_every_column():
    rep = make_report()
    console = Console(width=80, record=True)
    rep.print(console=console, per_instance=True)
    text = console.export_text()
    assert max(len(line) for line in text.splitlines()) <= 80
    assert "…" not in text  # nothing truncated
    labels = [threshold_label(t) for t in THRESHOLDS]
    wanted = [f"P@{x}" for x in labels] + [f"R@{x}" for x in labels] + ["L2(m)", "angle(rad)", "PCL@0.3",
                                                                          "n_gt", "n_pred"]
    assert set(wanted) <= header_names(text), set(wanted) - header_names(text)
    for name in ("all", "seq_a", "seq_b", "seq_a/0(cup_1)", "seq_a/1(cup_2)", "seq_b/0"):
        assert name in text
    # every value of the total row is shown: P 50.0 % at 0.25 m ... n_gt 5, n_pred 4
    cells = format_metric_cells(rep.total)
    rows = [line.split() for line in text.splitlines() if line.startswith("all ")]
    shown = [x for row in rows for x in row[1:]]
    assert shown == [cells[h] for h in wanted[:10]] + [cells["L2 (m)"], cells["angle (rad)"], cells["PCL@0.3"], "5", "4"]
    # and the rest of the undefined instance row says n/a, not 0.0
    assert any(line.startswith("seq_a/1(cup_2)") and "n/a" in line for line in text.splitlines())
    # wide terminals get one table
    assert len(rep.rich_tables(per_instance=True, width=200)) == 1


def test_comparison_terminal_tables_fit_80_columns():
    reports = {"kf (reference lift)": make_report(), "graph-causal (robust lift)": make_report(0.4),
               "nothing": empty_report()}
    tables = comparison_rich_tables(reports, baseline="kf (reference lift)", width=80)
    headers = ["".join(str(c.header).split()) for t in tables for c in t.columns if str(c.header) != "tracker"]
    md, _ = comparison_table(reports, baseline="kf (reference lift)")
    md_header = [c.strip().replace(" / kf (reference lift)", " / base") for c in md.splitlines()[0].strip("|").split("|")]
    assert headers == ["".join(h.split()) for h in md_header[1:]]  # every column, in order
    console = Console(width=80, record=True)
    print_comparison(reports, "kf (reference lift)", console)
    text = console.export_text()
    assert max(len(line) for line in text.splitlines()) <= 80 and "…" not in text
    assert "base = kf (reference lift)" in " ".join(text.split())
    nothing = [line for line in text.splitlines() if line.startswith("nothing")]
    assert len(nothing) == 2 and all("n/a" in line for line in nothing)


def test_plot_pr_writes_png(tmp_path):
    path = tmp_path / "plots" / "pr.png"
    plot_pr({"memory": make_report(), "shifted": make_report(0.4)}, path, title="test")
    data = path.read_bytes()
    assert len(data) > 1000 and data.startswith(PNG_MAGIC)
    plot_pr({"one": make_report()}, tmp_path / "one.png")
    assert (tmp_path / "one.png").read_bytes().startswith(PNG_MAGIC)


def test_comparison_table_layout_and_ratios():
    reports = {"memory": make_report(), "shifted": make_report(0.4)}
    md, text = comparison_table(reports, baseline="memory", ratio_columns=("P@0.25", "L2 (m)"))
    lines = md.splitlines()
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header == ["tracker", "P@0.25", "P@0.5", "P@0.75", "P@1.0", "P@1.5",
                      "R@0.25", "R@0.5", "R@0.75", "R@1.0", "R@1.5", "L2 (m)", "angle (rad)",
                      "P@0.25 / memory", "L2 (m) / memory"]
    memory = [c.strip() for c in lines[2].strip("|").split("|")]
    # Totals of make_report(): P = 50.0 % at 0.25 m, R = 40.0 %, L2 = 0.20 m; ratios against itself = 1.00.
    assert memory[:2] == ["memory", "50.0"] and memory[6] == "40.0" and memory[11] == "0.20"
    assert memory[-2:] == ["1.00", "1.00"]
    rows = list(csv.reader(io.StringIO(text)))
    assert rows[0] == header and [r[0] for r in rows[1:]] == ["memory", "shifted"]
    assert float(rows[1][1]) == pytest.approx(50.0)
    # Without a baseline: no ratio columns.
    md2, _ = comparison_table(reports)
    assert md2.splitlines()[0].count("|") == 14
    with pytest.raises(ValueError):
        comparison_table(reports, baseline="nope")


def test_comparison_undefined_cells_and_ratios():
    reports = {"memory": make_report(), "nothing": empty_report()}
    md, text = comparison_table(reports, baseline="memory", ratio_columns=("P@0.25", "R@0.25", "L2 (m)"))
    row = [c.strip() for c in md.splitlines()[3].strip("|").split("|")]
    # no predictions: precision, L2, angle and their ratios n/a; recall 0.0 and its ratio 0.00
    assert row == ["nothing"] + ["n/a"] * 5 + ["0.0"] * 5 + ["n/a", "n/a", "n/a", "0.00", "n/a"]
    rows = list(csv.reader(io.StringIO(text)))
    assert rows[2] == ["nothing"] + [""] * 5 + ["0.0"] * 5 + ["", "", "", "0.0", ""]
    # against an undefined baseline every ratio is n/a
    md, _ = comparison_table(reports, baseline="nothing", ratio_columns=("P@0.25",))
    assert md.splitlines()[2].endswith("| n/a |")


def test_render_report_and_comparison_formats():
    rep = make_report()
    assert render_report(rep, "md") == rep.to_markdown()
    assert render_report(rep, "csv") == rep.to_csv()
    assert json.loads(render_report(rep, "json")) == json.loads(json.dumps(rep.to_json_dict()))
    reports = {"memory": rep, "nothing": empty_report()}
    md, text = comparison_table(reports, baseline="memory")
    assert render_comparison(reports, "memory", "md") == md
    assert render_comparison(reports, "memory", "csv") == text
    d = json.loads(render_comparison(reports, "memory", "json"))
    header = next(csv.reader(io.StringIO(text)))
    assert d["baseline"] == "memory" and d["columns"] == header[1:]
    assert d["trackers"]["memory"]["P@0.25"] == pytest.approx(50.0)
    assert d["trackers"]["nothing"]["P@0.25"] is None and d["trackers"]["nothing"]["R@0.25"] == 0.0
    with pytest.raises(ValueError, match="expected one of md, csv, json"):
        render_report(rep, "xlsx")


def test_load_sequence_end_to_end(tmp_path):
    # pv_pose.json with 3 frames (the middle pose invalid), GT file, results folder with one frame missing.
    ident = np.eye(4)
    moved = np.eye(4)
    moved[3, :3] = [1.0, 2.0, 3.0]  # camera centre = last row
    poses = {"300": moved.tolist(), "100": ident.tolist(), "200": np.full((4, 4), np.nan).tolist()}
    (tmp_path / "pv_pose.json").write_text(json.dumps(poses))
    (tmp_path / "3d_center_annot.txt").write_text("100 300 0 1 0 0 0\n")
    (tmp_path / "labels.csv").write_text("cup_1\n")
    res = tmp_path / "res"
    res.mkdir()
    (res / "100.txt").write_text("0 0 1 0 0.9\n")
    (res / "300.txt").write_text("0 1 0 0 0.9\n")
    with pytest.warns(UserWarning):
        ts, centers = load_camera_centers(tmp_path / "pv_pose.json")
    assert ts.tolist() == [100, 200, 300]
    assert centers[0].tolist() == [0, 0, 0] and np.isnan(centers[1]).all() and centers[2].tolist() == [1, 2, 3]
    with pytest.warns(UserWarning):
        seq = load_sequence(tmp_path / "pv_pose.json", tmp_path / "3d_center_annot.txt", res,
                            tmp_path / "labels.csv")
    result, intervals = evaluate_loaded(seq)
    # Frame 100: d = √2 -> TP at 1.5 only. Frame 200: no file -> FN. Frame 300: exact -> TP.
    assert result.total.tp.tolist() == [1, 1, 1, 1, 2]
    assert (result.total.n_gt, result.total.n_pred) == (3, 2)
    assert seq.predictions.frames_without_file == 1
    # Angle: frame 100 from the origin, (1,0,0) vs (0,1,0) -> π/2; frame 300 exact -> 0; frame 200 no pose.
    assert result.total.angle_n == 2 and result.total.angle_rad == pytest.approx(np.pi / 4)
    rep = EvalReport()
    rep.add("s", result, intervals, seq.labels, seq.predictions.frames_without_file)
    assert rep.to_json_dict()["frames_without_file"] == 1
    assert "s/0(cup_1)" in rep.to_json_dict()["per_instance"]
