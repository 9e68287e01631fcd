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
