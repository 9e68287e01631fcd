"""The command line end to end on the tiny recording: track -> eval -> compare, and bad input."""

import json

import pytest
from conftest import TINY

from egograph.cli import main
from egograph.io.recording import Recording


@pytest.mark.slow
def test_synth_and_info(tmp_path, capsys):
    out = tmp_path / "rec"
    assert main(["synth", str(out), "--config", str(TINY), "--frames", "15", "--seed", "2", "--quiet",
                 "--set", "pv.rgb=false", "--set", "mvpe_photo_size=32"]) == 0
    assert main(["info", str(out), "--json", str(tmp_path / "info.json")]) == 0
    info = json.loads((tmp_path / "info.json").read_text())
    assert info["frames"] == 15 and len(info["instances"]) == 5 and "pose_error_vs_truth" in info
    assert "reported PV pose error" in capsys.readouterr().out


@pytest.mark.slow
def test_track_eval_compare(tiny_rec, tmp_path, capsys):
    rec = Recording.open(tiny_rec)
    for tracker in ("memory", "kf"):
        assert main(["track", str(tiny_rec), "--tracker", tracker, "--detections", "mvpe", "--quiet",
                     "--out", str(tmp_path / tracker)]) == 0
        files = sorted((tmp_path / tracker).glob("*.txt"))
        assert len(files) == len(rec)  # one file per PV frame, empty when nothing is predicted
    assert main(["eval", str(tiny_rec), str(tmp_path / "kf"), "--json", str(tmp_path / "e.json"),
                 "--plot", str(tmp_path / "pr.png")]) == 0
    e = json.loads((tmp_path / "e.json").read_text())
    for key in ("thresholds", "precision", "recall", "l2_m", "angle_rad", "n_gt", "n_pred", "per_sequence", "per_instance"):
        assert key in e
    assert e["thresholds"] == [0.25, 0.5, 0.75, 1.0, 1.5] and len(e["precision"]) == 5
    assert all(0 <= p <= 1 for p in e["precision"] + e["recall"])
    assert (tmp_path / "pr.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["compare", str(tiny_rec), str(tmp_path / "memory"), str(tmp_path / "kf"),
                 "--out", str(tmp_path / "cmp")]) == 0
    md = (tmp_path / "cmp" / "comparison.md").read_text()
    assert "memory" in md and "kf" in md and "P@0.25" in md


def test_bad_input_exits_2_naming_the_file(tmp_path, capsys):
    assert main(["info", str(tmp_path / "missing")]) == 2
    assert "missing: recording not found" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("frames: [\n")
    assert main(["synth", str(tmp_path / "o"), "--config", str(bad), "--quiet"]) == 2
    assert "bad.yaml:2: not valid YAML" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def true_stands(rec, intervals) -> list[bool]:
    """Per interval: within 0.25 m of a GT interval of its instance that it overlaps."""
    from egograph.eval.loader import load_gt_intervals

    gt = load_gt_intervals(rec.annotation_dir / "3d_center_annot.txt")
    return [any(g.instance == iv.instance and g.t_start <= iv.t_end and g.t_end >= iv.t_start
                and sum((a - b) ** 2 for a, b in zip(g.xyz, iv.xyz)) ** 0.5 < 0.25 for g in gt) for iv in intervals]


@pytest.mark.slow
def test_confident_graph_intervals_are_true_stands(tiny_rec, tmp_path):
    """Every interval the graph reports with confidence >= 0.8 is a true stand: on the tiny
    recording mug_2 is only ever matched on a clutter object (19 matches at scores 0.60-0.79, 13 at
    one place), which the graph reports (nothing better is known) at a confidence the low matcher
    scores of that place bring down (graph.places: place reality)."""
    from egograph.track.intervals import read_intervals_json

    rec = Recording.open(tiny_rec)
    assert main(["track", str(tiny_rec), "--tracker", "graph", "--detections", "mvpe", "--quiet",
                 "--out", str(tmp_path / "graph")]) == 0
    intervals, _ = read_intervals_json(tmp_path / "graph" / "intervals.json")
    assert all(ok for ok, iv in zip(true_stands(rec, intervals), intervals) if iv.confidence >= 0.8)
    assert sum(iv.confidence >= 0.8 for iv in intervals) >= 3
    mug_2 = [iv for iv in intervals if iv.instance == 1]
    assert mug_2 and all(iv.confidence < 0.2 for iv in mug_2)


@pytest.mark.slow
def test_graph_track_regt_smooth(tiny_rec, tmp_path, capsys):
    from egograph.track.intervals import read_intervals_json

    rec = Recording.open(tiny_rec)
    assert main(["track", str(tiny_rec), "--tracker", "graph", "--detections", "mvpe", "--quiet",
                 "--out", str(tmp_path / "graph"), "--eval"]) == 0
    assert len(list((tmp_path / "graph").glob("*.txt"))) == len(rec)
    intervals, meta = read_intervals_json(tmp_path / "graph" / "intervals.json")
    assert meta["tracker"] == "graph" and meta["backfilled"] is True and intervals
    out = capsys.readouterr().out
    assert "position intervals" in out and "back-filled" in out
    # the fitted detection noise scale is kept with the intervals, and said when it was fitted
    assert meta["noise_scale"] == meta["noise_scale_rounds"][-1] > 0
    assert ("detection noise scale fitted" in out) == (len(meta["noise_scale_rounds"]) > 1)
    true = true_stands(rec, intervals)
    assert sum(true) >= 2

    assert main(["track", str(tiny_rec), "--tracker", "graph-causal", "--detections", "mvpe", "--quiet",
                 "--out", str(tmp_path / "causal")]) == 0
    assert read_intervals_json(tmp_path / "causal" / "intervals.json")[1]["backfilled"] is False

    assert main(["regt", str(tiny_rec), "--out", str(tmp_path / "regt"), "--quiet"]) == 0
    for name in ("3d_center_annot.txt", "regt.json", "audit.md"):
        assert (tmp_path / "regt" / name).is_file()
    assert "annotated centres flagged" in (tmp_path / "regt" / "audit.md").read_text()

    assert main(["track", str(tiny_rec), "--tracker", "kf", "--detections", "mvpe", "--quiet",
                 "--out", str(tmp_path / "kf")]) == 0
    assert main(["smooth", str(tiny_rec), str(tmp_path / "kf"), "--out", str(tmp_path / "kf_graph"),
                 "--quiet"]) == 0
    assert len(list((tmp_path / "kf_graph").glob("*.txt"))) == len(rec)
    assert read_intervals_json(tmp_path / "kf_graph" / "intervals.json")[1]["smoothed"].endswith("kf")


def test_unknown_tracker_is_refused(tiny_rec, tmp_path, capsys):
    assert main(["track", str(tiny_rec), "--tracker", "bogus", "--out", str(tmp_path / "x"), "--quiet"]) == 2
    assert "bogus" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_every_option_has_help_and_tracker_lists_its_choices(capsys):
    import argparse

    from egograph.cli.main import build_parser
    from egograph.track.registry import TRACKERS

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = [(name, b.option_strings or b.dest) for name, sp in sub.choices.items() for b in sp._actions
               if not b.help and not isinstance(b, argparse._HelpAction)]
    assert missing == []
    assert main(["track", "--help"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in TRACKERS)


def test_an_unexpected_error_is_one_line_and_a_log_file(tiny_rec, tmp_path, capsys, monkeypatch):
    import egograph.steps.info as info

    def broken(rec, depth_samples=5, cfg=None):
        raise ValueError("operands could not be broadcast together")

    monkeypatch.setattr(info, "summarize", broken)
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    # A link planted at the old fixed name in the shared temporary folder is never followed.
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    (tmp_path / "egograph-error-info.log").symlink_to(victim)
    assert main(["info", str(tiny_rec)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error: ValueError: operands could not be broadcast" in err
    folder = tmp_path / "state" / "egograph"
    logs = list(folder.glob("egograph-error-info-*.log"))
    assert len(logs) == 1 and str(logs[0]) in err
    assert "Traceback" in logs[0].read_text() and "broken" in logs[0].read_text()
    assert (folder.stat().st_mode & 0o777, logs[0].stat().st_mode & 0o777) == (0o700, 0o600)
    assert victim.read_text() == "keep me\n"
    # A second crash gets a file of its own (exclusive creation, random name).
    assert main(["info", str(tiny_rec)]) == 1
    assert len(list(folder.glob("egograph-error-info-*.log"))) == 2


def test_min_confidence_is_a_probability_and_sets_both_operating_points(tmp_path, capsys):
    """--min-confidence is checked before anything is read, and --show-config shows it set for the
    offline and the causal graph (graph.answers.min_confidence, causal_min_confidence)."""
    assert main(["track", str(tmp_path / "none"), "--tracker", "graph", "--out", str(tmp_path / "o"),
                      "--min-confidence", "1.5"]) == 2
    assert "--min-confidence 1.5" in capsys.readouterr().err
    from egograph.cli.main import _min_confidence
    from egograph.core.config import load_config
    from egograph.core.resources import default_config
    from egograph.steps.settings import EgographConfig

    cfg = load_config(EgographConfig, default_config())
    _min_confidence(type("A", (), {"min_confidence": 0.6})(), cfg)
    assert cfg.graph.answers.min_confidence == cfg.graph.answers.causal_min_confidence == 0.6
