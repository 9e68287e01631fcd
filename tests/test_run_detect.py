"""``egograph run --stages detect,lift,track,eval``: the front-end as a stage of the Dask run.

The dataset: two short copies of the session's synthetic recording with PV RGB (``tiny_rgb_rec``)
and a third without its ``pv/`` folder. The front-end runs with a tiny random ONNX encoder at a
32-pixel input (its detections are poor, but they are what lift must read). Checked: one detection
file per PV frame per sequence, lift's observations are exactly those detections (count and
provenance), the sequence without PV images fails its detect with the PV folder named while its
later stages are skipped and the other sequences complete, and a second run of the same plan
computes nothing.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import copy_with_pose_error, no_pose_error

pytest.importorskip("onnxruntime")
pytest.importorskip("open3d")

from egograph.core.config import load_config  # noqa: E402
from egograph.core.resources import default_config  # noqa: E402
from egograph.geometry.observations import Observations  # noqa: E402
from egograph.steps.run import close_client, open_client, plan_run, run_dataset  # noqa: E402
from tests.test_frontend import tiny_encoder  # noqa: E402

STAGES = ["detect", "lift", "track", "eval"]
TRACKERS = ["kf"]
FRAMES = {"a": 20, "b": 14}


@pytest.fixture(scope="module")
def dataset(tiny_rgb_rec, tmp_path_factory) -> Path:
    """a: the first 20 frames of the RGB recording, b: its first 14, nopv: b without pv/ (true poses)."""
    ds = tmp_path_factory.mktemp("run_detect") / "ds"
    for name, n in FRAMES.items():
        copy_with_pose_error(tiny_rgb_rec, ds / name, no_pose_error, frames=n)
    shutil.copytree(ds / "b", ds / "nopv")
    shutil.rmtree(next((ds / "nopv").glob("*/pv")))
    return ds


def config(encoder: Path):
    from egograph.steps.settings import EgographConfig

    cfg = load_config(EgographConfig, default_config())
    cfg.frontend.encoder = str(encoder)
    cfg.frontend.input_size = 32
    cfg.frontend.threads = 1  # one core per Dask worker
    cfg.frontend.proposals = "image"  # (with this encoder no geometry proposal reaches the threshold)
    cfg.frontend.mvpe_proposals = ""  # the same for MVPE
    return cfg


def detection_rows(folder: Path) -> int:
    return sum(len(f.read_text().split("\n")) - 1 for f in folder.glob("*.txt"))


@pytest.mark.slow
def test_run_detects_lifts_its_detections_and_skips_done_work(dataset, tmp_path):
    cfg = config(tiny_encoder(tmp_path / "enc.onnx", side=32))
    runs = tmp_path / "runs"
    client = open_client(2)
    try:
        plan = plan_run(dataset, runs, cfg, stages=STAGES, trackers=TRACKERS, detections="mvpe")
        first = run_dataset(plan, cfg, client=client)
        again = plan_run(dataset, runs, cfg, stages=STAGES, trackers=TRACKERS, detections="mvpe")
        second = run_dataset(again, cfg, client=client)
    finally:
        close_client(client)
    tasks = {t.key: t for t in plan.tasks}
    assert again.name == plan.name

    # the sequence without PV images: its detect fails naming the folder, what reads it is skipped
    assert [(r["key"], r["status"]) for r in first.failed] == [
        ("detect/nopv", "failed"), ("lift/nopv", "skipped"), ("track/nopv/kf", "skipped"), ("eval/nopv/kf", "skipped")]
    pv = next((dataset / "nopv").glob("*/pv_pose.json")).parent / "pv"
    err = first.results["detect/nopv"]["error"]
    assert str(pv) in err and "folder missing" in err and "<ts>.png" in err, err
    assert first.results["lift/nopv"]["error"] == "needs detect/nopv (failed)"

    for seq, n in FRAMES.items():
        det = tasks[f"detect/{seq}"].out
        assert det.parent.name == seq and det.name.startswith("detect-mvpe-")
        assert len(list(det.glob("*.txt"))) == n  # one file per PV frame
        rows = detection_rows(det)
        assert rows > 0
        own = next(dataset.joinpath(seq).glob("detections/*/mvpe"))
        assert rows != detection_rows(own)  # (the recording's own simulated set differs)
        lifted = tasks[f"lift/{seq}"].out
        assert Observations.read_provenance(lifted)["detections"]["spec"] == str(det)
        assert len(Observations.load(lifted)) == rows  # one observation per detection of detect's files
        assert (plan.folder / seq / "detections").resolve() == det
        assert first.results[f"eval/{seq}/kf"]["status"] == "ok"
    assert list(first.summary["evaluation"]["kf"]["per_sequence"]) == ["a", "b"]
    assert first.summary["sequences"]["a"] == {"detect": "ok", "lift": "ok", "track/kf": "ok", "eval/kf": "ok"}

    # run again: every finished output is reused, nothing computed; the failure is the same
    ok = [k for k, r in first.results.items() if r["status"] == "ok"]
    assert all(second.results[k]["status"] == "ok" and second.results[k]["reused"] for k in ok), second.results
    assert second.summary == first.summary
    assert np.isfinite(first.summary["evaluation"]["kf"]["n_pred"])


@pytest.mark.slow
def test_run_iterates_rounds_of_adaptation_each_output_its_own(dataset, tmp_path):
    """``--stages detect,lift,track,eval,adapt`` with ``adapt.rounds`` 2: per sequence round 1's
    adapt reads round 0's graph results and detections, round 2's round 1's; every round writes its
    own detections, observations, results and evaluation (named -r1, -r2), says which round and
    which results taught it, and a second run computes nothing."""
    cfg = config(tiny_encoder(tmp_path / "enc.onnx", side=32))
    cfg.adapt.rounds = 2
    cfg.adapt.min_support, cfg.adapt.min_confidence, cfg.adapt.min_positives, cfg.adapt.min_holdback = 1, 0.0, 1, 0.0
    cfg.adapt.background_frames = 5
    cfg.graph.min_observations = 1
    runs = tmp_path / "runs"
    stages = [*STAGES, "adapt"]
    with pytest.raises(Exception, match="add graph to --trackers"):
        plan_run(dataset, runs, cfg, stages=stages, trackers=["kf"], detections="mvpe")
    client = open_client(2)
    try:
        plan = plan_run(dataset, runs, cfg, stages=stages, trackers=["graph"], detections="mvpe")
        first = run_dataset(plan, cfg, client=client)
        second = run_dataset(plan_run(dataset, runs, cfg, stages=stages, trackers=["graph"], detections="mvpe"), cfg,
                             client=client)
    finally:
        close_client(client)
    import json

    tasks = {t.key: t for t in plan.tasks}
    res = first.results
    assert res["adapt/a@r1"]["status"] == "ok", res["adapt/a@r1"]
    for r in (1, 2):
        ad = json.loads((tasks[f"adapt/a@r{r}"].out / "adapt.json").read_text())
        assert ad["round"] == r
        teacher = tasks["track/a/graph" if r == 1 else f"track/a/graph@r{r - 1}"].out
        assert ad["taught_by"]["results"] == str(teacher)
        det = tasks[f"detect/a@r{r}"].out
        assert det.name.startswith(f"detect-mvpe-r{r}-") and len(list(det.glob("*.txt"))) == FRAMES["a"]
        assert json.loads((det / "egograph.json").read_text())["inputs"]["adapt"]["round"] == r
        assert (plan.folder / "a" / f"detections-r{r}").resolve() == det
        assert res[f"eval/a/graph@r{r}"]["status"] == "ok"
    assert len({tasks[k].out for k in ("detect/a", "detect/a@r1", "detect/a@r2")}) == 3   # none overwritten
    assert set(first.summary["rounds"]) == {"0", "1", "2"}
    assert first.summary["rounds"]["1"]["adapt"]["a"]["heads"] == sorted(first.summary["rounds"]["1"]["adapt"]["a"]["heads"])
    r2 = first.summary["rounds"]["2"]["adapt"]
    assert "holdback_auc" in r2["a"]
    # sequence b: its round-2 adapt either ran or its result says why not (e.g. round 1's graph
    # results held no stand to learn from); the run goes on either way
    assert "b" in r2 or (res["adapt/b@r2"]["status"] != "ok" and res["adapt/b@r2"].get("error"))
    ok = [k for k, r in res.items() if r["status"] == "ok"]
    assert all(second.results[k]["reused"] for k in ok), [k for k in ok if not second.results[k]["reused"]]
