"""Evaluation reports: several sequences of one tracker, and trackers side by side.

Units everywhere: precision/recall/PCL as fractions 0-1 in JSON and CSV,
percent with one decimal in Markdown and terminal tables; L2 in metres; angle
in radians; break-time error in seconds. A ratio whose denominator is zero is
reported as 0.0 together with its ``n`` (``n_pred``, ``n_gt``, ``l2_n``,
``angle_n``), and tables print ``(n=0)`` beside it.
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

from egograph.eval.intervals import IntervalScore
from egograph.eval.protocol import THRESHOLDS, Counts, SequenceResult
from egograph.io.atomic import atomic_write_bytes, atomic_write_text

DEFAULT_RATIO_COLUMNS = ("P@0.25", "P@1.5", "R@0.25", "R@1.5", "L2 (m)", "angle (rad)")


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
    ) -> None:
        """Add one sequence's result (names must be unique; thresholds must match)."""
        if name in self.sequences:
            raise ValueError(f"sequence {name!r} is already in the report")
        if result.total.thresholds != tuple(self.thresholds):
            raise ValueError(f"sequence {name!r} uses thresholds {result.total.thresholds}, report {self.thresholds}")
        self.sequences[name] = SequenceEval(name, result, intervals, labels, int(frames_without_file))

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
        out["per_sequence"] = {}
        out["per_instance"] = {}
        for s in self.sequences.values():
            seq = counts_metrics(s.result.total)
            seq["intervals"] = s.intervals.to_dict() if s.intervals is not None else None
            seq["n_frames"] = s.result.n_frames
            seq["frames_without_file"] = s.frames_without_file
            seq["labels"] = list(s.labels) if s.labels is not None else None
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
                       int(seq.get("frames_without_file", 0)))
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
        """One row per scope (total, sequence, instance); fractions 0-1, metres, radians."""
        labels = [threshold_label(t) for t in self.thresholds]
        header = ["scope", "name", "n_gt", "n_pred"]
        header += [f"P@{x}" for x in labels] + [f"R@{x}" for x in labels]
        header += [f"{k}@{x}" for k in ("TP", "FP", "FN") for x in labels]
        header += ["l2_m", "l2_n", "angle_rad", "angle_n", "pcl_0.3"]
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(header)
        for scope, name, c in self._rows():
            w.writerow(
                [scope, name, c.n_gt, c.n_pred]
                + [repr(float(x)) for x in c.precision] + [repr(float(x)) for x in c.recall]
                + [int(x) for arr in (c.tp, c.fp, c.fn) for x in arr]
                + [repr(c.l2_m), c.l2_n, repr(c.angle_rad), c.angle_n, repr(c.pcl)]
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

    def rich_table(self, per_instance: bool = False, title: str = "IT3DEgo evaluation"):
        """A compact ``rich.table.Table``: the total, then sequences (and instances if asked).

        Precision, recall and PCL in percent; ``*`` marks a ratio with a zero denominator (n=0).
        """
        from rich import box
        from rich.table import Table

        labels = [threshold_label(t) for t in self.thresholds]
        cols = [f"P@{x}" for x in labels] + [f"R@{x}" for x in labels] + ["L2 (m)", "angle (rad)", "PCL@0.3"]
        table = Table(title=title, box=box.SIMPLE_HEAD, padding=(0, 1), collapse_padding=True, pad_edge=False,
                      caption="P, R, PCL in %; * = n=0")
        table.add_column("name", no_wrap=True)
        for h in cols + ["n_gt", "n_pred"]:  # two-line headers keep the columns narrow
            header = h.replace("@", "@\n").replace(" (", "\n(")
            table.add_column(header, justify="right", no_wrap=True, min_width=5)
        scope = None
        for kind, name, c in self._rows(per_instance):
            if scope is not None and kind != scope:
                table.add_section()
            scope = kind
            cells = format_metric_cells(c)
            table.add_row(name, *(cells[h].replace(" (n=0)", "*") for h in cols), str(c.n_gt), str(c.n_pred))
        return table

    def print(self, console=None, per_instance: bool = False) -> None:
        """Print the terminal table (and the interval line) with rich."""
        from rich.console import Console

        console = console or Console()
        console.print(self.rich_table(per_instance))
        iv = self.intervals
        if iv is not None:
            med = iv.median_break_error_s
            console.print(
                f"intervals: recovered {iv.n_recovered}/{iv.n_true} ({100 * iv.recovered_fraction:.1f} %), "
                f"median break error {'n/a' if med is None else f'{med:.2f} s'} "
                f"({len(iv.break_errors_s)}/{iv.n_breaks} breaks)"
            )


# --------------------------------------------------------------------------- formatting


def _pct(x: float, n: int) -> str:
    return f"{100 * x:.1f}" + ("" if n else " (n=0)")


def format_metric_cells(c: Counts) -> dict[str, str]:
    """Display strings of one Counts: ``P@τ``/``R@τ`` and PCL in percent, L2 and angle to 2 decimals."""
    cells = {}
    for t, p, r in zip(c.thresholds, c.precision, c.recall):
        cells[f"P@{threshold_label(t)}"] = _pct(p, c.n_pred)
        cells[f"R@{threshold_label(t)}"] = _pct(r, c.n_gt)
    cells["L2 (m)"] = f"{c.l2_m:.2f}" + ("" if c.l2_n else " (n=0)")
    cells["angle (rad)"] = f"{c.angle_rad:.2f}" + ("" if c.angle_n else " (n=0)")
    cells["PCL@0.3"] = _pct(c.pcl, c.n_gt)
    return cells


def _metric_values(c: Counts) -> dict[str, float]:
    """Numeric values of the comparison columns (percent for P/R, metres, radians)."""
    vals = {}
    for t, p, r in zip(c.thresholds, c.precision, c.recall):
        vals[f"P@{threshold_label(t)}"] = 100 * float(p)
        vals[f"R@{threshold_label(t)}"] = 100 * float(r)
    vals["L2 (m)"] = c.l2_m
    vals["angle (rad)"] = c.angle_rad
    return vals


def _md_escape(text: str) -> str:
    return str(text).replace("|", "\\|")


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]], n_left: int = 1) -> list[str]:
    """GitHub Markdown table lines; the first ``n_left`` columns left-aligned, the others right-aligned."""
    lines = ["| " + " | ".join(_md_escape(h) for h in header) + " |"]
    lines.append("|" + "|".join(":---" if i < n_left else "---:" for i in range(len(header))) + "|")
    lines += ["| " + " | ".join(_md_escape(x) for x in row) + " |" for row in rows]
    return lines


def comparison_table(
    reports: Mapping[str, EvalReport],
    baseline: str | None = None,
    ratio_columns: Sequence[str] = DEFAULT_RATIO_COLUMNS,
) -> tuple[str, str]:
    """Trackers side by side, in the layout of the paper's tables -> (markdown, csv).

    Rows are trackers; columns ``P@0.25 … P@1.5``, ``R@0.25 … R@1.5`` (percent,
    one decimal), ``L2 (m)``, ``angle (rad)``. With ``baseline`` (a key of
    ``reports``), one extra column per name in ``ratio_columns`` holds
    ``value / baseline value`` (two decimals; ``n/a`` when the baseline value is 0).
    The CSV holds the same cells, with full-precision numbers.
    """
    if not reports:
        raise ValueError("no reports to compare")
    if baseline is not None and baseline not in reports:
        raise ValueError(f"baseline {baseline!r} is not one of {sorted(reports)}")
    thresholds = next(iter(reports.values())).thresholds
    for name, rep in reports.items():
        if tuple(rep.thresholds) != tuple(thresholds):
            raise ValueError(f"tracker {name!r} uses thresholds {rep.thresholds}, expected {thresholds}")
    labels = [threshold_label(t) for t in thresholds]
    metric_cols = [f"P@{x}" for x in labels] + [f"R@{x}" for x in labels] + ["L2 (m)", "angle (rad)"]
    ratios = [c for c in ratio_columns if c in metric_cols] if baseline is not None else []
    unknown = [c for c in (ratio_columns if baseline is not None else []) if c not in metric_cols]
    if unknown:
        raise ValueError(f"unknown ratio column(s) {unknown}; choose from {metric_cols}")
    header = ["tracker"] + metric_cols + [f"{c} / {baseline}" for c in ratios]
    base_vals = _metric_values(reports[baseline].total) if baseline is not None else {}

    md_rows, csv_rows = [], []
    for name, rep in reports.items():
        total = rep.total
        cells, vals = format_metric_cells(total), _metric_values(total)
        md = [name] + [cells[c] for c in metric_cols]
        cs: list = [name] + [repr(vals[c]) for c in metric_cols]
        for c in ratios:
            b = base_vals[c]
            if b == 0 or not math.isfinite(b):
                md.append("n/a")
                cs.append("")
            else:
                md.append(f"{vals[c] / b:.2f}")
                cs.append(repr(vals[c] / b))
        md_rows.append(md)
        csv_rows.append(cs)

    md_text = "\n".join(markdown_table(header, md_rows)) + "\n"
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(csv_rows)
    return md_text, buf.getvalue()


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
