"""Steps: results returned in memory equal what is written; a step with ``overwrite=False`` skips
work already done for the same inputs and configuration; every output folder describes itself
(resolved configuration, version, command) and honours the umask; the CLI's light paths work
without their other arguments."""

from __future__ import annotations

import json
import os
import stat

import pytest
import yaml

from egograph import __version__
from egograph.cli import main
from egograph.core.config import load_config
from egograph.steps.evaluate import evaluate
from egograph.steps.lift import lift
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.steps.track import read_result, track
from egograph.track.intervals import read_intervals_json


@pytest.fixture(scope="module")
def cfg():
    return load_config(EgographConfig)


@pytest.fixture(scope="module")
def rec(tiny_rec, cfg):
    return open_recording(tiny_rec, cfg)


@pytest.fixture(scope="module")
def obs(rec, cfg, tmp_path_factory):
    path = tmp_path_factory.mktemp("obs") / "mvpe.npz"
    o, report = lift(rec, "mvpe", cfg, path, progress=False)
    assert report is not None and path.is_file()
    return o, path


@pytest.mark.slow
def test_lift_is_skipped_for_the_same_provenance_and_redone_for_other_knobs(rec, cfg, obs):
    o, path = obs
    again, report = lift(rec, "mvpe", cfg, path, progress=False)
    assert report is None  # read back, not lifted again
    assert again.provenance == o.provenance and (again.world == o.world).sum() == (o.world == o.world).sum()
    other = load_config(EgographConfig, None, ["lift.mode=reference"])
    _, report = lift(rec, "mvpe", other, path, progress=False)
    assert report is not None  # other knobs: other provenance, lifted again (and the file now holds those)
    assert Observations_provenance(path)["lift"]["mode"] == "reference"


def Observations_provenance(path):
    from egograph.geometry.observations import Observations

    return Observations.read_provenance(path)


def test_track_writes_one_self_describing_folder_and_skips_a_repeat(rec, cfg, obs, tmp_path):
    o, _ = obs
    out = tmp_path / "graph"
    result = track(rec, "graph", o, cfg, out)
    names = {p.name for p in out.iterdir()}
    assert {"intervals.json", "config.yaml", "egograph.json"} <= names
    assert len([n for n in names if n.endswith(".txt")]) == len(rec)
    # every answer with its confidence beside the per-frame files, which hold the operating point's
    assert "answers.tsv" in names and result.answers is not None
    back = read_result(out, rec)
    assert back.answers == result.answers
    floor = cfg.graph.answers.min_confidence
    assert back.per_frame == {t: [p for p in v if p.score >= floor] for t, v in result.answers.items()}
    run = json.loads((out / "egograph.json").read_text())
    assert run["step"] == "track" and run["egograph_version"] == __version__ and run["inputs"]["tracker"] == "graph"
    # the saved configuration is a config file the loader reads back to the same values
    assert load_config(EgographConfig, out / "config.yaml") == cfg
    doc = json.loads((out / "intervals.json").read_text())
    assert doc["schema_version"] == 1 and doc["sequence"] == rec.name and doc["n_frames"] == len(rec)
    assert doc["instances"] and doc["units"]["xyz"].startswith("m")
    first = doc["intervals"][0]
    assert first["frame_start"] <= first["frame_end"] and first["name"] == doc["instances"][first["instance"]]
    assert first["t_start_s"] == pytest.approx((first["t_start"] - doc["first_frame_ticks"]) / 1e7)
    back, _ = read_intervals_json(out / "intervals.json")
    assert back == result.intervals
    before = (out / "egograph.json").stat().st_mtime_ns
    again = track(rec, "graph", o, cfg, out)  # same inputs and configuration: read back, not re-run
    assert (out / "egograph.json").stat().st_mtime_ns == before
    assert again.per_frame == result.per_frame and again.intervals == result.intervals


def test_evaluation_in_memory_equals_from_disk_and_scores_the_intervals(rec, cfg, obs, tmp_path):
    o, _ = obs
    out = tmp_path / "graph"
    result = track(rec, "graph", o, cfg, out)
    mem, disk = evaluate(rec, result), evaluate(rec, out)
    assert mem.to_json_dict() == disk.to_json_dict()
    assert read_result(out, rec).intervals == result.intervals
    # intervals scored as the tracker gave them: drop one and the recovered count can only fall
    fewer = type(result)(per_frame=result.per_frame, intervals=result.intervals[1:], metadata=result.metadata)
    assert evaluate(rec, fewer).intervals.n_recovered <= mem.intervals.n_recovered


@pytest.mark.slow
def test_every_output_honours_the_umask(tiny_rec, tmp_path):
    old = os.umask(0o022)
    try:
        assert main(["track", str(tiny_rec), "--tracker", "kf", "--detections", "mvpe", "--quiet",
                     "--out", str(tmp_path / "kf")]) == 0
        assert main(["lift", str(tiny_rec), "--detections", "svoe", "--quiet", "--out", str(tmp_path / "o.npz")]) == 0
        assert main(["eval", str(tiny_rec), str(tmp_path / "kf"), "--json", str(tmp_path / "e.json")]) == 0
        assert main(["regt", str(tiny_rec), "--out", str(tmp_path / "regt"), "--quiet"]) == 0
    finally:
        os.umask(old)
    for p in [tmp_path / "kf", tmp_path / "regt", *tmp_path.rglob("*")]:
        mode = stat.S_IMODE(p.stat().st_mode)
        assert mode == (0o755 if p.is_dir() else 0o644), (p, oct(mode))


def test_show_config_needs_no_other_argument_and_round_trips_as_yaml(capsys, tmp_path):
    assert main(["track", "--show-config", "--format", "yaml", "--set", "graph.chunk_s=0.25"]) == 0
    text = capsys.readouterr().out
    f = tmp_path / "c.yaml"
    f.write_text(text)
    assert yaml.safe_load(text)["graph"]["chunk_s"] == 0.25
    assert load_config(EgographConfig, f).graph.chunk_s == 0.25
    assert main(["synth", "--show-config"]) == 0
    assert "frames" in capsys.readouterr().out
    assert main(["--version"]) == 0
    assert __version__ in capsys.readouterr().out


def test_bad_config_value_is_one_line_naming_the_key(tiny_rec, tmp_path, capsys):
    assert main(["track", str(tiny_rec), "--tracker", "kf", "--out", str(tmp_path / "x"),
                 "--set", "lift.mode=bogus"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "lift.mode" in err and "bogus" in err and not (tmp_path / "x").exists()
