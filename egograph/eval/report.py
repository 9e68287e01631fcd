"""Evaluation reports: several sequences of one tracker, and trackers side by side.

Units: precision/recall/PCL as fractions 0-1 in a report's JSON and CSV, percent in the
comparison CSV/JSON, percent with one decimal in Markdown and terminal tables; L2 in metres;
angle in radians; break-time error in seconds.

Undefined values -- precision without predictions (``n_pred == 0``), recall and PCL without GT
(``n_gt == 0``), L2/angle without a matched pair (``l2_n``/``angle_n == 0``), a NaN, a ratio to
an undefined or zero baseline -- print as ``n/a`` in Markdown and terminal tables and as an empty
cell in CSV, never as 0.0 (which would read as a result). A report's JSON keeps the protocol's
0.0 together with the counts that say it is undefined (``n_pred``, ``n_gt``, ``l2_n``,
``angle_n``), so it stays exact and additive.

Terminal tables (:meth:`EvalReport.rich_tables`, :func:`comparison_rich_tables`) fit the
console width -- 80 columns included -- by stacking tables that repeat the name column, never
by dropping a column; :func:`render_report` and :func:`render_comparison` give every column as
Markdown, CSV or JSON text.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from egograph.eval.curves import CALIBRATION_TAU, ScoredAnswers, pr_curves, reliability
from egograph.eval.intervals import IntervalScore
from egograph.eval.protocol import THRESHOLDS, Counts, SequenceResult
from egograph.io.atomic import atomic_write_bytes, atomic_write_text

DEFAULT_RATIO_COLUMNS = ("P@0.25", "P@1.5", "R@0.25", "R@1.5", "L2 (m)", "angle (rad)")

AP_THRESHOLDS = (0.25, 1.0)
"""Thresholds (metres) whose average precision over confidence the comparison shows beside the
IT3DEgo columns (when a tracker carries confidences: :mod:`egograph.eval.curves`)."""

FORMATS = ("md", "csv", "json")
"""Text formats of :func:`render_report` and :func:`render_comparison`."""

NA = "n/a"
"""How tables print an undefined value."""

TERMINAL_WIDTH = 80
"""Width the terminal tables fit when no console width is known."""


def threshold_label(t: float) -> str:
    """``0.25 -> "0.25"``, ``1.0 -> "1.0"``: as the paper writes thresholds."""
    s = f"{float(t):g}"
    return s if ("." in s or "e" in s) else s + ".0"


def counts_metrics(c: Counts) -> dict:
    """Metrics and the raw sums behind them, JSON-ready (fractions 0-1, metres, radians)."""
    return {
        "thresholds": list(c.thresholds),
        "precision": [float(x) for x in c.precision],
        "recall": [float(x) for x in c.recall],
        "l2_m": float(c.l2_m),
        "angle_rad": float(c.angle_rad),
        "pcl_0.3": float(c.pcl),
        "n_gt": int(c.n_gt),
        "n_pred": int(c.n_pred),
        "tp": [int(x) for x in c.tp],
        "fp": [int(x) for x in c.fp],
        "fn": [int(x) for x in c.fn],
        "l2_n": int(c.l2_n),
        "angle_n": int(c.angle_n),
        "l2_sum": float(c.l2_sum),
        "angle_sum": float(c.angle_sum),
        "pcl_hits": int(c.pcl_hits),
    }


def counts_from_metrics(d: Mapping) -> Counts:
    """Inverse of :func:`counts_metrics` (exact: it reads the raw sums)."""
    return Counts(
        thresholds=tuple(d["thresholds"]),
        tp=d["tp"], fp=d["fp"], fn=d["fn"],
        n_gt=int(d["n_gt"]), n_pred=int(d["n_pred"]),
        l2_sum=float(d["l2_sum"]), l2_n=int(d["l2_n"]),
        angle_sum=float(d["angle_sum"]), angle_n=int(d["angle_n"]),
        pcl_hits=int(d["pcl_hits"]),
    )


@dataclass
class SequenceEval:
    """One evaluated sequence: counts, optional interval score, instance names (index = id)."""

    name: str
    result: SequenceResult
    intervals: IntervalScore | None = None
    labels: Sequence[str] | None = None
    frames_without_file: int = 0
    answers: ScoredAnswers | None = None   # every answer with its confidence, scored (egograph.eval.curves)
    ap: Mapping[str, float] | None = None  # AP per threshold read back from JSON (where the answers are not kept)

    def instance_key(self, instance: int) -> str:
        """``"seq/3(cup_1)"``, or ``"seq/3"`` when the name is unknown."""
        name = None
        if self.labels is not None and 0 <= instance < len(self.labels):
            name = self.labels[instance]
        return f"{self.name}/{instance}" + (f"({name})" if name else "")


@dataclass
class EvalReport:
    """All sequences of one tracker; totals sum counts over sequences (not means of ratios)."""

    thresholds: tuple[float, ...] = THRESHOLDS
    sequences: dict[str, SequenceEval] = field(default_factory=dict)

    def add(
        self,
        name: str,
        result: SequenceResult,
        intervals: IntervalScore | None = None,
        labels: Sequence[str] | None = None,
        frames_without_file: int = 0,
        answers: ScoredAnswers | None = None,
        ap: Mapping[str, float] | None = None,
    ) -> None:
        """Add one sequence's result (names must be unique; thresholds must match); ``answers``:
        every answer with its confidence, for the precision-recall curves; ``ap``: its AP per
        threshold where only that was kept (read back from JSON)."""
        if name in self.sequences:
            raise ValueError(f"sequence {name!r} is already in the report")
        if result.total.thresholds != tuple(self.thresholds):
            raise ValueError(f"sequence {name!r} uses thresholds {result.total.thresholds}, report {self.thresholds}")
        self.sequences[name] = SequenceEval(name, result, intervals, labels, int(frames_without_file), answers,
                                            dict(ap) if ap is not None else None)

    @property
    def total(self) -> Counts:
        return sum((s.result.total for s in self.sequences.values()), Counts(self.thresholds))

    @property
    def intervals(self) -> IntervalScore | None:
        scores = [s.intervals for s in self.sequences.values() if s.intervals is not None]
        return sum(scores, IntervalScore()) if scores else None

    @property
    def n_frames(self) -> int:
        return sum(s.result.n_frames for s in self.sequences.values())

    @property
    def answers(self) -> ScoredAnswers | None:
        """Every sequence's scored answers pooled (None unless every sequence has them)."""
        seqs = list(self.sequences.values())
        if not seqs or any(s.answers is None for s in seqs):
            return None
        return sum((s.answers for s in seqs), ScoredAnswers(self.thresholds))

    def curves(self) -> dict:
        """Pooled precision-recall curves over confidence per threshold ({} without answers)."""
        a = self.answers
        return pr_curves(a) if a is not None else {}

    @property
    def frames_without_file(self) -> int:
        return sum(s.frames_without_file for s in self.sequences.values())

    # ------------------------------------------------------------------ JSON

    def to_json_dict(self) -> dict:
        """Totals, then ``per_sequence`` and ``per_instance`` (``"seq/id(name)"``) with the same metrics."""
        out = counts_metrics(self.total)
        iv = self.intervals
        out["intervals"] = iv.to_dict() if iv is not None else None
        out["n_sequences"] = len(self.sequences)
        out["n_frames"] = self.n_frames
        out["frames_without_file"] = self.frames_without_file
        pooled = self.answers
        if pooled is not None:  # curves over confidence (all-point interpolated AP) and calibration
            out["curves"] = {threshold_label(t): c.to_json_dict() for t, c in pr_curves(pooled).items()}
            tau = CALIBRATION_TAU if CALIBRATION_TAU in pooled.thresholds else pooled.thresholds[0]
            out["reliability"] = reliability(pooled, tau).to_json_dict()
        out["per_sequence"] = {}
        out["per_instance"] = {}
        for s in self.sequences.values():
            seq = counts_metrics(s.result.total)
            seq["intervals"] = s.intervals.to_dict() if s.intervals is not None else None
            seq["n_frames"] = s.result.n_frames
            seq["frames_without_file"] = s.frames_without_file
            seq["labels"] = list(s.labels) if s.labels is not None else None
            if s.answers is not None:
                seq["ap"] = {threshold_label(t): round(c.ap, 6) for t, c in pr_curves(s.answers).items()}
            elif s.ap is not None:
                seq["ap"] = dict(s.ap)
            out["per_sequence"][s.name] = seq
            for inst, c in sorted(s.result.per_instance.items()):
                row = counts_metrics(c)
                row["sequence"] = s.name
                row["instance"] = int(inst)
                out["per_instance"][s.instance_key(inst)] = row
        return out

    @classmethod
    def from_json_dict(cls, d: Mapping) -> EvalReport:
        """Rebuild a report from :meth:`to_json_dict` output (counts are exact)."""
        report = cls(thresholds=tuple(d["thresholds"]))
        per_inst: dict[str, dict[int, Counts]] = {}
        for row in d.get("per_instance", {}).values():
            per_inst.setdefault(row["sequence"], {})[int(row["instance"])] = counts_from_metrics(row)
        for name, seq in d["per_sequence"].items():
            result = SequenceResult(counts_from_metrics(seq), per_inst.get(name, {}), int(seq.get("n_frames", 0)))
            iv = seq.get("intervals")
            report.add(name, result, IntervalScore.from_dict(iv) if iv else None, seq.get("labels"),
                       int(seq.get("frames_without_file", 0)), ap=seq.get("ap"))
        return report

    def write_json(self, path: str | Path) -> None:
        atomic_write_text(path, json.dumps(self.to_json_dict(), indent=2) + "\n")

    # ------------------------------------------------------------------ rows

    def _rows(self, per_instance: bool = True) -> list[tuple[str, str, Counts]]:
        """(scope, name, counts): the total, each sequence, then each instance."""
        rows = [("total", "all", self.total)]
        rows += [("sequence", s.name, s.result.total) for s in self.sequences.values()]
        if per_instance:
            for s in self.sequences.values():
                rows += [("instance", s.instance_key(i), c) for i, c in sorted(s.result.per_instance.items())]
        return rows

    def to_csv(self) -> str:
        """One row per scope (total, sequence, instance); fractions 0-1, metres, radians.

        An undefined ratio (see the module doc: no predictions, no GT, no matched pair, NaN) is an
        empty cell; the ``n_gt``/``n_pred``/``l2_n``/``angle_n`` columns say why.
        """
        labels = [threshold_label(t) for t in self.thresholds]
        header = ["scope", "name", "n_gt", "n_pred"]
        header += [f"P@{x}" for x in labels] + [f"R@{x}" for x in labels]
        header += [f"{k}@{x}" for k in ("TP", "FP", "FN") for x in labels]
        header += ["l2_m", "l2_n", "angle_rad", "angle_n", "pcl_0.3"]
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(header)
        for scope, name, c in self._rows():
            p_ok, r_ok = c.n_pred > 0, c.n_gt > 0
            w.writerow(
                [scope, name, c.n_gt, c.n_pred]
                + [_csv_number(x, p_ok) for x in c.precision] + [_csv_number(x, r_ok) for x in c.recall]
                + [int(x) for arr in (c.tp, c.fp, c.fn) for x in arr]
                + [_csv_number(c.l2_m, c.l2_n > 0), c.l2_n, _csv_number(c.angle_rad, c.angle_n > 0), c.angle_n,
                   _csv_number(c.pcl, r_ok)]
            )
        return buf.getvalue()

    def write_csv(self, path: str | Path) -> None:
        atomic_write_text(path, self.to_csv())

    def _table_rows(self, per_instance: bool) -> tuple[list[str], list[list[str]]]:
        labels = [threshold_label(t) for t in self.thresholds]
        header = ["scope", "name"] + [f"P@{x}" for x in labels] + [f"R@{x}" for x in labels]
        header += ["L2 (m)", "angle (rad)", "PCL@0.3", "n_gt", "n_pred"]
        rows = []
        for scope, name, c in self._rows(per_instance):
            m = format_metric_cells(c)
            rows.append(
                [scope, name] + [m[f"P@{x}"] for x in labels] + [m[f"R@{x}"] for x in labels]
                + [m["L2 (m)"], m["angle (rad)"], m["PCL@0.3"], str(c.n_gt), str(c.n_pred)]
            )
        return header, rows

    def to_markdown(self, title: str = "IT3DEgo evaluation") -> str:
        """Totals, per sequence and per instance (percent, one decimal), plus interval scores."""
        header, rows = self._table_rows(per_instance=True)
        lines = [f"# {title}", ""]
        lines.append(
            f"{len(self.sequences)} sequence(s), {self.n_frames} PV frames"
            f" ({self.frames_without_file} without a results file, counted as no predictions)."
            " Precision, recall and PCL in percent; L2 in metres; angle in radians."
        )
        lines.append("")
        lines += markdown_table(header, rows, n_left=2)
        iv = self.intervals
        lines.append("")
        lines.append("## Intervals")
        lines.append("")
        if iv is None:
            lines.append("No interval scores.")
        else:
            med = iv.median_break_error_s
            lines.append(
                f"Recovered {iv.n_recovered}/{iv.n_true} true intervals"
                f" ({100 * iv.recovered_fraction:.1f} %); median break-time error "
                + (f"{med:.2f} s" if med is not None else "n/a")
                + f" over {len(iv.break_errors_s)} of {iv.n_breaks} true breaks."
            )
        return "\n".join(lines) + "\n"

    def write_markdown(self, path: str | Path, title: str = "IT3DEgo evaluation") -> None:
        atomic_write_text(path, self.to_markdown(title))

    def rich_tables(self, per_instance: bool = False, title: str = "IT3DEgo evaluation",
                    width: int = TERMINAL_WIDTH) -> list:
        """``rich.table.Table`` objects that together hold every column and each fit ``width``
        terminal columns: the total, then sequences (and instances if asked), the name column
        repeated in each; one table when the width allows. P, R, PCL in percent; L2 in metres;
        angle in radians; ``n/a`` marks an undefined value.
        """
        labels = [threshold_label(t) for t in self.thresholds]
        groups = [[f"P@{x}" for x in labels], [f"R@{x}" for x in labels], ["L2 (m)", "angle (rad)", "PCL@0.3"],
                  ["n_gt", "n_pred"]]
        names, cells, sections, scope = [], [], [], None
        for kind, name, c in self._rows(per_instance):
            sections.append(scope is not None and kind != scope)
            scope = kind
            m = format_metric_cells(c)
            m["n_gt"], m["n_pred"] = str(c.n_gt), str(c.n_pred)
            names.append(name)
            cells.append(m)
        return fit_tables(title, "name", names, groups, cells, width, sections=sections,
                          caption="P, R, PCL in %; n/a = undefined (no predictions, no GT)")

    def rich_table(self, per_instance: bool = False, title: str = "IT3DEgo evaluation", width: int = TERMINAL_WIDTH):
        """:meth:`rich_tables` as one renderable (``rich.console.Group``)."""
        from rich.console import Group

        return Group(*self.rich_tables(per_instance, title, width))

    def print(self, console=None, per_instance: bool = False) -> None:
        """Print the terminal table (and the interval line) with rich."""
        from rich.console import Console

        console = console or Console()
        for table in self.rich_tables(per_instance, width=console.width):
            console.print(table)
        iv = self.intervals
        if iv is not None:
            med = iv.median_break_error_s
            console.print(
                f"intervals: recovered {iv.n_recovered}/{iv.n_true} ({100 * iv.recovered_fraction:.1f} %), "
                f"median break error {'n/a' if med is None else f'{med:.2f} s'} "
                f"({len(iv.break_errors_s)}/{iv.n_breaks} breaks)"
            )


# --------------------------------------------------------------------------- formatting


def _defined(x: float, ok: bool) -> bool:
    return bool(ok) and math.isfinite(float(x))


def _csv_number(x: float, ok: bool) -> str:
    """Full-precision CSV cell; empty when undefined."""
    return repr(float(x)) if _defined(x, ok) else ""


def _pct(x: float, ok: bool) -> str:
    return f"{100 * x:.1f}" if _defined(x, ok) else NA


def _fixed2(x: float, ok: bool) -> str:
    return f"{x:.2f}" if _defined(x, ok) else NA


def format_metric_cells(c: Counts) -> dict[str, str]:
    """Display strings of one Counts: ``P@τ``/``R@τ`` and PCL in percent (one decimal), L2 and
    angle to 2 decimals; ``n/a`` where undefined (no predictions, no GT, no matched pair, NaN)."""
    cells = {}
    for t, p, r in zip(c.thresholds, c.precision, c.recall):
        cells[f"P@{threshold_label(t)}"] = _pct(p, c.n_pred > 0)
        cells[f"R@{threshold_label(t)}"] = _pct(r, c.n_gt > 0)
    cells["L2 (m)"] = _fixed2(c.l2_m, c.l2_n > 0)
    cells["angle (rad)"] = _fixed2(c.angle_rad, c.angle_n > 0)
    cells["PCL@0.3"] = _pct(c.pcl, c.n_gt > 0)
    return cells


def _metric_values(c: Counts) -> dict[str, float | None]:
    """Numeric values of the comparison columns (percent for P/R, metres, radians); None where undefined."""
    vals: dict[str, float | None] = {}
    for t, p, r in zip(c.thresholds, c.precision, c.recall):
        vals[f"P@{threshold_label(t)}"] = 100 * float(p) if _defined(p, c.n_pred > 0) else None
        vals[f"R@{threshold_label(t)}"] = 100 * float(r) if _defined(r, c.n_gt > 0) else None
    vals["L2 (m)"] = float(c.l2_m) if _defined(c.l2_m, c.l2_n > 0) else None
    vals["angle (rad)"] = float(c.angle_rad) if _defined(c.angle_rad, c.angle_n > 0) else None
    return vals


def _md_escape(text: str) -> str:
    return str(text).replace("|", "\\|")


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]], n_left: int = 1) -> list[str]:
    """GitHub Markdown table lines; the first ``n_left`` columns left-aligned, the others right-aligned."""
    lines = ["| " + " | ".join(_md_escape(h) for h in header) + " |"]
    lines.append("|" + "|".join(":---" if i < n_left else "---:" for i in range(len(header))) + "|")
    lines += ["| " + " | ".join(_md_escape(x) for x in row) + " |" for row in rows]
    return lines


@dataclass
class _Comparison:
    """The cells of a comparison: ``header`` (tracker, metrics, ratios), per tracker the display
    strings and the numbers (None where undefined)."""

    header: list[str]
    metric_cols: list[str]
    ratio_cols: list[str]
    baseline: str | None
    text: dict[str, list[str]]
    numbers: dict[str, list[float | None]]


def _comparison(reports: Mapping[str, EvalReport], baseline: str | None,
                ratio_columns: Sequence[str]) -> _Comparison:
    if not reports:
        raise ValueError("no reports to compare")
    if baseline is not None and baseline not in reports:
        raise ValueError(f"baseline {baseline!r} is not one of {sorted(reports)}")
    thresholds = next(iter(reports.values())).thresholds
    for name, rep in reports.items():
        if tuple(rep.thresholds) != tuple(thresholds):
            raise ValueError(f"tracker {name!r} uses thresholds {rep.thresholds}, expected {thresholds}")
    labels = [threshold_label(t) for t in thresholds]
    ap_cols = [f"AP@{threshold_label(t)}" for t in AP_THRESHOLDS if t in thresholds] \
        if any(rep.answers is not None for rep in reports.values()) else []
    metric_cols = [f"P@{x}" for x in labels] + [f"R@{x}" for x in labels] + ap_cols + ["L2 (m)", "angle (rad)"]
    ratios = [c for c in ratio_columns if c in metric_cols] if baseline is not None else []
    unknown = [c for c in (ratio_columns if baseline is not None else []) if c not in metric_cols]
    if unknown:
        raise ValueError(f"unknown ratio column(s) {unknown}; choose from {metric_cols}")
    header = ["tracker"] + metric_cols + [f"{c} / {baseline}" for c in ratios]
    base_vals = _metric_values(reports[baseline].total) if baseline is not None else {}
    text, numbers = {}, {}
    for name, rep in reports.items():
        total = rep.total
        cells, vals = format_metric_cells(total), _metric_values(total)
        curves = rep.curves() if ap_cols else {}
        for t in AP_THRESHOLDS:
            c = curves.get(t)
            vals[f"AP@{threshold_label(t)}"] = 100 * c.ap if c is not None and c.n_gt else None
            cells[f"AP@{threshold_label(t)}"] = _pct(c.ap, True) if c is not None and c.n_gt else NA
        row_text = [cells[c] for c in metric_cols]
        row_nums = [vals[c] for c in metric_cols]
        for c in ratios:
            b, v = base_vals[c], vals[c]
            if b is None or v is None or b == 0:
                row_text.append(NA)
                row_nums.append(None)
            else:
                row_text.append(f"{v / b:.2f}")
                row_nums.append(v / b)
        text[name], numbers[name] = row_text, row_nums
    return _Comparison(header, metric_cols, ratios, baseline, text, numbers)


def comparison_table(
    reports: Mapping[str, EvalReport],
    baseline: str | None = None,
    ratio_columns: Sequence[str] = DEFAULT_RATIO_COLUMNS,
) -> tuple[str, str]:
    """Trackers side by side, in the layout of the paper's tables -> (markdown, csv).

    Rows are trackers; columns ``P@0.25 … P@1.5``, ``R@0.25 … R@1.5`` (percent,
    one decimal), ``L2 (m)``, ``angle (rad)``. With ``baseline`` (a key of
    ``reports``), one extra column per name in ``ratio_columns`` holds
    ``value / baseline value`` (two decimals). Undefined values (no predictions, no GT,
    no matched pair, NaN; a ratio to an undefined or zero baseline) are ``n/a``.
    The CSV holds the same cells, with full-precision numbers, and an empty cell where
    the Markdown says ``n/a``.
    """
    cmp = _comparison(reports, baseline, ratio_columns)
    md_rows = [[name] + cells for name, cells in cmp.text.items()]
    md_text = "\n".join(markdown_table(cmp.header, md_rows)) + "\n"
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cmp.header)
    for name, nums in cmp.numbers.items():
        w.writerow([name] + ["" if v is None else repr(v) for v in nums])
    return md_text, buf.getvalue()


def comparison_json(
    reports: Mapping[str, EvalReport],
    baseline: str | None = None,
    ratio_columns: Sequence[str] = DEFAULT_RATIO_COLUMNS,
) -> dict:
    """The comparison's every column as JSON-ready numbers: ``{"baseline", "columns",
    "trackers": {name: {column: value}}}``, with the CSV's units (P/R in percent, L2 in metres,
    angle in radians, ratios unitless) and null where undefined."""
    cmp = _comparison(reports, baseline, ratio_columns)
    return {
        "baseline": baseline,
        "columns": cmp.header[1:],
        "trackers": {name: dict(zip(cmp.header[1:], nums)) for name, nums in cmp.numbers.items()},
    }


def comparison_rich_tables(
    reports: Mapping[str, EvalReport],
    baseline: str | None = None,
    ratio_columns: Sequence[str] = DEFAULT_RATIO_COLUMNS,
    width: int = TERMINAL_WIDTH,
    title: str = "trackers compared",
) -> list:
    """:func:`comparison_table` as ``rich`` tables that each fit ``width`` terminal columns
    (stacked, the tracker column repeated; every column kept). Ratio columns are headed
    ``P@0.25 / base`` with the baseline named in the caption."""
    cmp = _comparison(reports, baseline, ratio_columns)
    ratio_heads = [f"{c} / base" for c in cmp.ratio_cols]
    p_cols = [c for c in cmp.metric_cols if c.startswith("P@")]
    r_cols = [c for c in cmp.metric_cols if c.startswith("R@")]
    ap_cols = [c for c in cmp.metric_cols if c.startswith("AP@")]
    groups = [p_cols, r_cols, [*ap_cols, "L2 (m)", "angle (rad)"]] + ([ratio_heads] if ratio_heads else [])
    cells = [dict(zip(cmp.metric_cols + ratio_heads, row)) for row in cmp.text.values()]
    caption = "P, R in %; n/a = undefined"
    if any(c.startswith("AP@") for c in cmp.metric_cols):
        caption += "; AP: all-point interpolated, over confidence, in %"
    if baseline is not None:
        caption += f"; base = {baseline}"
    return fit_tables(title, "tracker", list(cmp.text), groups, cells, width, caption=caption)


def print_comparison(reports: Mapping[str, EvalReport], baseline: str | None = None, console=None,
                     ratio_columns: Sequence[str] = DEFAULT_RATIO_COLUMNS) -> None:
    """Print :func:`comparison_rich_tables` at the console's width."""
    from rich.console import Console

    console = console or Console()
    for table in comparison_rich_tables(reports, baseline, ratio_columns, width=console.width):
        console.print(table)


# --------------------------------------------------------------------------- text output


def render_report(report: EvalReport, fmt: str) -> str:
    """One tracker's report as text with every column: ``md`` (:meth:`EvalReport.to_markdown`),
    ``csv`` (:meth:`EvalReport.to_csv`) or ``json`` (:meth:`EvalReport.to_json_dict`, as
    :meth:`EvalReport.write_json` writes it)."""
    if fmt == "md":
        return report.to_markdown()
    if fmt == "csv":
        return report.to_csv()
    if fmt == "json":
        return json.dumps(report.to_json_dict(), indent=2) + "\n"
    raise ValueError(f"format {fmt!r}: expected one of {', '.join(FORMATS)}")


def render_comparison(reports: Mapping[str, EvalReport], baseline: str | None = None, fmt: str = "md",
                      ratio_columns: Sequence[str] = DEFAULT_RATIO_COLUMNS) -> str:
    """Trackers side by side as text with every column: ``md`` and ``csv`` as
    :func:`comparison_table` returns them, ``json`` as :func:`comparison_json`."""
    if fmt in ("md", "csv"):
        md, text = comparison_table(reports, baseline, ratio_columns)
        return md if fmt == "md" else text
    if fmt == "json":
        return json.dumps(comparison_json(reports, baseline, ratio_columns), indent=2) + "\n"
    raise ValueError(f"format {fmt!r}: expected one of {', '.join(FORMATS)}")


# --------------------------------------------------------------------------- terminal tables

NAME_MIN_WIDTH = 12
"""Narrowest the name column is folded to before metric columns move to another table."""


def _header(h: str) -> str:
    """Two-line headers keep the metric columns narrow: ``P@\\n0.25``, ``L2\\n(m)``, ``P@0.25\\n/ base``."""
    if " / " in h:
        return h.replace(" / ", "\n/ ")
    return h.replace("@", "@\n").replace(" (", "\n(")


def _new_table(title: str | None, name_header: str, caption: str | None):
    from rich import box
    from rich.table import Table

    # no padding: the box's blank column separators leave one space between columns (80 columns
    # hold the name and the ten P/R columns)
    table = Table(title=title, box=box.SIMPLE_HEAD, padding=(0, 0), show_edge=False, caption=caption)
    table.add_column(name_header, overflow="fold", min_width=min(NAME_MIN_WIDTH, len(name_header)))
    return table


def _fill(table, columns: Sequence[str], names: Sequence[str], cells: Sequence[Mapping[str, str]],
          sections: Sequence[bool]) -> None:
    for h in columns:
        table.add_column(_header(h), justify="right", no_wrap=True, min_width=5)
    for name, row, new_section in zip(names, cells, sections):
        if new_section:
            table.add_section()
        table.add_row(name, *(row[h] for h in columns))


def _width(table) -> int:
    from rich.console import Console

    return Console(width=100_000).measure(table).maximum


def fit_tables(title: str | None, name_header: str, names: Sequence[str], groups: Sequence[Sequence[str]],
               cells: Sequence[Mapping[str, str]], width: int, sections: Sequence[bool] | None = None,
               caption: str | None = None) -> list:
    """Rich tables holding every column of ``groups`` (lists of column names, kept together
    where they fit) for the rows ``names``/``cells``, each at most ``width`` terminal columns.

    Groups are packed in order into a table while it fits with the name column at its natural
    width or, if the names are long, folded to ``NAME_MIN_WIDTH``; a group that fits no table
    alone is split column by column. The title goes on the first table, the caption on the widest.
    """
    sections = list(sections) if sections is not None else [False] * len(names)
    longest = max([len(n) for n in names] + [len(name_header)])
    name_room = min(longest, max(NAME_MIN_WIDTH, len(name_header)))

    def needed(columns: Sequence[str]) -> int:
        probe = _new_table(None, name_header, None)
        _fill(probe, columns, [""] * len(cells), cells, [False] * len(cells))
        return _width(probe) - len(name_header) + max(name_room, len(name_header))

    pieces: list[list[str]] = []
    for group in groups:
        for part in ([list(group)] if needed(group) <= width else [[c] for c in group]):
            if pieces and needed(pieces[-1] + part) <= width:
                pieces[-1] += part
            else:
                pieces.append(list(part))
    widths = [needed(columns) for columns in pieces]
    with_caption = max(range(len(pieces)), key=lambda k: (widths[k], k))  # captions wrap at their table's width
    tables = []
    for k, columns in enumerate(pieces):
        table = _new_table(title if k == 0 else None, name_header, caption if k == with_caption else None)
        _fill(table, columns, names, cells, sections)
        tables.append(table)
    return tables


# --------------------------------------------------------------------------- plot


def plot_pr(reports: Mapping[str, EvalReport], path: str | Path, title: str | None = None) -> None:
    """PNG of precision (left) and recall (right), in percent, against threshold (metres), one line per tracker."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not reports:
        raise ValueError("no reports to plot")
    fig = Figure(figsize=(10, 4), dpi=100)
    FigureCanvasAgg(fig)
    ax_p, ax_r = fig.subplots(1, 2, sharey=True)
    for name, rep in reports.items():
        c = rep.total
        t = np.asarray(c.thresholds)
        ax_p.plot(t, 100 * c.precision, marker="o", label=name)
        ax_r.plot(t, 100 * c.recall, marker="o", label=name)
    for ax, what in ((ax_p, "precision"), (ax_r, "recall")):
        ax.set_xlabel("threshold τ (m)")
        ax.set_ylabel(f"{what} (%)")
        ax.set_title(what)
        ax.set_ylim(0, 100)
        ax.grid(True, alpha=0.3)
    ax_r.legend(loc="lower right", fontsize="small")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())
