"""``egograph run``: a dataset's sequences as Dask tasks, resumable, pooled as the reference pools.

The dataset: three short synthetic sequences cut from the session's tiny recording (other
lengths, other poses) and one whose detections are missing (its lift fails; the others go on). Three runs of it, each
into a fresh RUNS folder: an uninterrupted ``egograph run`` (the reference), one on a LocalCluster
of 2 workers where the worker running a lift is SIGKILLed mid-task, and an ``egograph run``
SIGKILLed as a whole after its first finished step and run again. All three summaries must be
the same bytes, and the reference's pooled counts equal the reference evaluator's loop restated
here.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import copy_with_pose_error, no_pose_error

import egograph
from egograph.core.config import load_config
from egograph.core.errors import ConfigError, InputError
from egograph.core.resources import default_config
from egograph.steps.dataset import list_dataset, sequence_ids
from egograph.steps.run import plan_run, resolve_stages

PACKAGE_ROOT = Path(egograph.__file__).resolve().parents[1]
TRACKERS = "memory,kf"
THRESHOLDS = (0.25, 0.5, 0.75, 1.0, 1.5)
RUN = "import sys; from egograph.cli.main import main; sys.exit(main(sys.argv[1:]))"


def config():
    from egograph.steps.settings import EgographConfig

    return load_config(EgographConfig, default_config())


def fake_sequence(folder: Path) -> Path:
    folder.mkdir(parents=True)
    (folder / "pv_pose.json").write_text("{}")
    return folder


# ------------------------------------------------------------------ fast: dataset, stages, plan


def test_dataset_ids_of_synth_outputs_release_and_plain_roots(tmp_path):
    for name in ("b", "a"):  # a folder of `egograph synth` outputs sharing one sequence name
        fake_sequence(tmp_path / "synth" / name / "tiny_seq")
    assert [(s.id, s.path.parent.name) for s in list_dataset(tmp_path / "synth")] == [("a", "a"), ("b", "b")]
    for name in ("vid_2", "vid_1"):
        fake_sequence(tmp_path / "plain" / name)
    assert [s.id for s in list_dataset(tmp_path / "plain")] == ["vid_1", "vid_2"]
    assert sequence_ids([Path("x/s"), Path("x/t")]) == ["s", "t"]
    assert sequence_ids([Path("x/s"), Path("x/s2"), Path("y/s")]) == ["x-s", "x-s2", "y-s"]
    assert sequence_ids([Path("x/s"), Path("y/s")]) == ["x", "y"]
    assert sequence_ids([Path("p/x/s"), Path("q/x/s")]) == ["x-s", "x-s"]  # refused by list_dataset
    (tmp_path / "empty" / "sub").mkdir(parents=True)
    with pytest.raises(InputError, match="no sequence found"):
        list_dataset(tmp_path / "empty")
    with pytest.raises(InputError, match="not found"):
        list_dataset(tmp_path / "missing")


def test_stages_bring_what_they_need():
    assert resolve_stages(["eval"]) == ["lift", "track", "eval"]
    assert resolve_stages(["regt", "refine"]) == ["refine", "regt"]
    assert resolve_stages(None) == ["lift", "track", "eval"]
    assert resolve_stages(["lift", "detect"]) == ["detect", "lift"]
    assert resolve_stages(["detect"]) == ["detect"]  # never brought: it replaces the recording's detections
    with pytest.raises(ConfigError, match="unknown stage 'trak'"):
        resolve_stages(["trak"])


def test_plan_names_and_cache_keys_follow_the_configuration(tmp_path):
    fake_sequence(tmp_path / "ds" / "a" / "s")
    fake_sequence(tmp_path / "ds" / "b" / "s")
    cfg = config()
    p1 = plan_run(tmp_path / "ds", tmp_path / "runs", cfg, stages=["eval"], trackers=["graph", "kf"])
    assert p1.name == plan_run(tmp_path / "ds", tmp_path / "other", cfg, stages=["eval"], trackers=["graph", "kf"]).name
    assert p1.name.startswith("ds-")
    assert [t.key for t in p1.tasks[:5]] == ["lift/a", "track/a/graph", "eval/a/graph", "track/a/kf", "eval/a/kf"]
    assert p1.tasks[2].deps == ["track/a/graph"] and p1.tasks[1].deps == ["lift/a"]
    cfg.graph.score_threshold = 0.61  # a tracker knob: the trackers' outputs move, the lift stays
    p2 = plan_run(tmp_path / "ds", tmp_path / "runs", cfg, stages=["eval"], trackers=["graph", "kf"])
    out1, out2 = ({t.key: t.out for t in p.tasks} for p in (p1, p2))
    assert p2.name != p1.name
    assert out1["lift/a"] == out2["lift/a"]
    assert out1["track/a/graph"] != out2["track/a/graph"] and out1["eval/a/graph"] != out2["eval/a/graph"]
    cfg.lift.mode = "reference"
    p3 = plan_run(tmp_path / "ds", tmp_path / "runs", cfg, stages=["eval"], trackers=["kf"])
    assert {t.key: t.out for t in p3.tasks}["lift/a"] != out1["lift/a"]
    p4 = plan_run(tmp_path / "ds", tmp_path / "runs", cfg, stages=["refine", "regt", "lift"])
    assert [t.key for t in p4.tasks[:3]] == ["refine/a", "lift/a", "regt/a"]
    assert p4.tasks[1].deps == ["refine/a"] and p4.tasks[1].spec["poses"] == str(p4.tasks[0].out)
    # detect: lift reads its folder; a frontend knob moves detect and everything after it
    p5 = plan_run(tmp_path / "ds", tmp_path / "runs", cfg, stages=["detect", "eval"], trackers=["kf"], detections="mvpe")
    t5 = {t.key: t for t in p5.tasks}
    assert [t.key for t in p5.tasks[:4]] == ["detect/a", "lift/a", "track/a/kf", "eval/a/kf"]
    assert t5["detect/a"].out.name.startswith("detect-mvpe-") and t5["detect/a"].spec["enroll"] == "mvpe"
    assert t5["lift/a"].deps == ["detect/a"] and t5["lift/a"].spec["detections"] == str(t5["detect/a"].out)
    assert t5["lift/a"].out != {t.key: t.out for t in p3.tasks}["lift/a"]  # not the recording's own mvpe set
    cfg.frontend.similarity_threshold = 0.7
    t6 = {t.key: t for t in plan_run(tmp_path / "ds", tmp_path / "runs", cfg, stages=["detect", "eval"], trackers=["kf"],
                                     detections="mvpe").tasks}
    assert all(t6[k].out != t5[k].out for k in ("detect/a", "lift/a", "track/a/kf", "eval/a/kf"))
    assert {t.key: t.out for t in plan_run(tmp_path / "ds", tmp_path / "runs", cfg, stages=["eval"],
                                           trackers=["kf"]).tasks}["lift/a"] == {t.key: t.out for t in p3.tasks}["lift/a"]
    p7 = plan_run(tmp_path / "ds", tmp_path / "runs", cfg, stages=["refine", "detect", "lift"], detections="svoe")
    assert [(t.key, t.deps) for t in p7.tasks[:3]] == [("refine/a", []), ("detect/a", ["refine/a"]),
                                                       ("lift/a", ["detect/a"])]
    assert p7.tasks[1].spec["poses"] == str(p7.tasks[0].out)
    with pytest.raises(ConfigError, match="--detections gt: the detect stage produces one of svoe, mvpe"):
        plan_run(tmp_path / "ds", tmp_path / "runs", cfg, stages=["detect"], detections="gt")


def test_cli_refuses_unusable_input_before_writing(tmp_path, capsys):
    from egograph.cli.main import main

    (tmp_path / "empty").mkdir()
    assert main(["run", str(tmp_path / "empty"), "--out", str(tmp_path / "runs")]) == 2
    assert "no sequence found" in capsys.readouterr().err
    fake_sequence(tmp_path / "ds" / "s")
    assert main(["run", str(tmp_path / "ds"), "--out", str(tmp_path / "runs"), "--stages", "detect,track",
                 "--detections", "gt"]) == 2
    assert "the detect stage produces one of svoe, mvpe" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "ds"), "--out", str(tmp_path / "runs"), "--trackers", "nope"]) == 2
    assert not (tmp_path / "runs").exists()


# ------------------------------------------------------------------ slow: the runs


@pytest.fixture(scope="module")
def dataset(tiny_rec, tmp_path_factory) -> Path:
    """Cut from the session's tiny recording: a, its first 48 frames with the true poses; b, 36
    frames with the true poses moved 3 cm; c, 24 frames moved 5 cm the other way; broken: a copy of
    c without its detections."""
    ds = tmp_path_factory.mktemp("run") / "ds"

    def shifted(offset):
        def error(ts, pv):
            err = np.tile(np.eye(4), (len(ts), 1, 1))
            err[:, 3, :3] = offset  # row vectors: a world-frame translation
            return err
        return error

    copy_with_pose_error(tiny_rec, ds / "a", no_pose_error, frames=48)
    copy_with_pose_error(tiny_rec, ds / "b", shifted([0.03, 0.0, -0.01]), frames=36)
    copy_with_pose_error(tiny_rec, ds / "c", shifted([-0.05, 0.02, 0.0]), frames=24)
    shutil.copytree(ds / "c", ds / "broken")
    shutil.rmtree(ds / "broken" / "detections")
    return ds


def cli(*args: str, **kw) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(PACKAGE_ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.Popen([sys.executable, "-c", RUN, "run", *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def run_args(dataset: Path, runs: Path) -> list[str]:
    return [str(dataset), "--out", str(runs), "--trackers", TRACKERS, "--workers", "2", "--quiet"]


@pytest.fixture(scope="module")
def reference_run(dataset, tmp_path_factory) -> Path:
    """An uninterrupted ``egograph run``; RUNS/latest."""
    runs = tmp_path_factory.mktemp("ref") / "runs"
    p = cli(*run_args(dataset, runs))
    out, err = p.communicate(timeout=600)
    assert p.returncode == 1, err  # the broken sequence failed, the others are complete
    assert "lift failed" in out and "broken" in out
    return runs / "latest"


def read_frame_file(path: Path) -> dict:
    """``instance -> xyz`` of one results file (a later line for an instance overwrites)."""
    preds = {}
    if path.is_file():
        for line in path.read_text().split("\n"):
            v = line.replace(",", " ").split()
            if v:
                preds[int(v[0])] = np.array([float(x) for x in v[1:4]])
    return preds


def reference_pooling(dataset: Path, run: Path, tracker: str, seqs: list[str]) -> dict:
    """design.md §2 restated: every PV frame of every sequence; per frame n_pred += predictions; per
    GT interval covering the frame n_gt += 1, no prediction -> FN at every τ, else TP where d <= τ,
    else FP and FN; FP += predictions - matched; sums over all frames of all sequences, then divided."""
    tp, fp, fn = (np.zeros(len(THRESHOLDS), int) for _ in range(3))
    n_pred = n_gt = 0
    l2, l2_n = 0.0, 0
    for seq in seqs:
        seq_dir = next(p for p in (dataset / seq).iterdir() if (p / "pv_pose.json").is_file())
        frames = sorted(int(t) for t in json.loads((seq_dir / "pv_pose.json").read_text()))
        gt = []
        for line in (dataset / seq / "annotations" / seq_dir.name / "3d_center_annot.txt").read_text().split("\n"):
            v = line.replace(",", " ").split()
            if v:
                gt.append((int(v[0]), int(v[1]), int(v[2]), np.array([float(x) for x in v[3:6]])))
        for ts in frames:
            preds = read_frame_file(run / seq / tracker / f"{ts}.txt")
            n_pred += len(preds)
            matched = []
            for t0, t1, inst, xyz in gt:
                if not t0 <= ts <= t1:
                    continue
                n_gt += 1
                if inst not in preds:
                    fn += 1
                    continue
                d = float(np.linalg.norm(preds[inst] - xyz))
                for k, tau in enumerate(THRESHOLDS):
                    if d <= tau:
                        tp[k] += 1
                    else:
                        fp[k] += 1
                        fn[k] += 1
                matched.append(inst)
                l2, l2_n = l2 + d, l2_n + 1
            fp += len(preds) - len(matched)
    return {"tp": tp.tolist(), "fp": fp.tolist(), "fn": fn.tolist(), "n_pred": n_pred, "n_gt": n_gt,
            "precision": (tp / n_pred).tolist(), "recall": (tp / n_gt).tolist(), "l2_m": l2 / l2_n}


@pytest.mark.slow
def test_pooled_evaluation_equals_the_reference_pooling(dataset, reference_run):
    summary = json.loads((reference_run / "summary.json").read_text())
    assert [(f["sequence"], f["stage"], f["status"]) for f in summary["failures"]] == [
        ("broken", "lift", "failed"), ("broken", "track/memory", "skipped"), ("broken", "eval/memory", "skipped"),
        ("broken", "track/kf", "skipped"), ("broken", "eval/kf", "skipped")]
    assert "detection" in summary["failures"][0]["error"]
    for tracker in TRACKERS.split(","):
        pooled = summary["evaluation"][tracker]
        assert list(pooled["per_sequence"]) == ["a", "b", "c"]
        ref = reference_pooling(dataset, reference_run, tracker, ["a", "b", "c"])
        assert ref["n_pred"] > 0 and ref["tp"][-1] > 0  # something to count
        for key in ("tp", "fp", "fn", "n_pred", "n_gt"):
            assert pooled[key] == ref[key], (tracker, key)
        assert pooled["precision"] == pytest.approx(ref["precision"], rel=1e-12)
        assert pooled["recall"] == pytest.approx(ref["recall"], rel=1e-12)
        assert pooled["l2_m"] == pytest.approx(ref["l2_m"], rel=1e-9)
        # pooled, not a mean of per-sequence ratios: the sums of the per-sequence rows
        rows = pooled["per_sequence"].values()
        assert pooled["tp"] == np.sum([r["tp"] for r in rows], axis=0).tolist()
        assert pooled["n_pred"] == sum(r["n_pred"] for r in rows)
        # the per-sequence eval.json is what `egograph eval --json` writes for that sequence
        one = json.loads((reference_run / "b" / f"eval-{tracker}.json").read_text())
        assert one["per_sequence"]["b"] == pooled["per_sequence"]["b"]


def executing(dask_worker) -> list[str]:
    return [str(ts.key) for ts in dask_worker.state.executing]


def listening(pid: int) -> list[tuple[str, int]]:
    import psutil

    return [(c.laddr.ip, c.laddr.port) for c in psutil.Process(pid).net_connections("inet")
            if c.status == psutil.CONN_LISTEN]


@pytest.mark.slow
def test_worker_killed_during_a_task_loses_nothing(dataset, reference_run, tmp_path):
    from egograph.steps.run import close_client, open_client, run_dataset, worker_threads

    cfg = config()
    plan = plan_run(dataset, tmp_path / "runs", cfg, stages=["eval"], trackers=TRACKERS.split(","))
    client = open_client(2)
    killed = {}
    try:
        pids = client.run(os.getpid)
        assert len(pids) == 2
        # each local worker is one core: detect's onnxruntime takes that many threads, not the machine's
        assert worker_threads() is None and client.submit(worker_threads, pure=False).result() == 1
        for pid in [os.getpid(), *pids.values()]:  # the local cluster listens on loopback only, no 8787
            socks = listening(pid)
            assert socks and all(ip == "127.0.0.1" and port != 8787 for ip, port in socks), socks

        def kill_a_lift():
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                for addr, keys in client.run(executing).items():
                    lifts = [k for k in keys if "-lift/" in k and not k.endswith("/broken")]
                    if lifts:  # a lift of a good sequence takes a second or more
                        os.kill(pids[addr], signal.SIGKILL)
                        killed[addr] = lifts
                        return
                time.sleep(0.05)

        watcher = threading.Thread(target=kill_a_lift)
        watcher.start()
        outcome = run_dataset(plan, cfg, client=client)
        watcher.join()
        assert len(client.run(os.getpid)) == 2  # the nanny started another worker
        key = ""
        if killed:
            key = next(iter(killed.values()))[0]
            story = client.run_on_scheduler(lambda dask_scheduler: [list(s) for s in dask_scheduler.story(key)])
            started = [s for s in story if s[0] == key and s[2] == "processing"]
            assert len(started) == 2, story  # sent to a worker twice: the killed one, then another
    finally:
        close_client(client)
    assert killed, "no lift seen running"
    key = key.removeprefix(f"egograph-{plan.name}-")
    assert outcome.results[key]["status"] == "ok" and not outcome.results[key]["reused"]
    assert [r["key"] for r in outcome.failed] == [t.key for t in plan.tasks if t.sequence == "broken"]
    assert (plan.folder / "summary.json").read_bytes() == (reference_run / "summary.json").read_bytes()


def outputs_state(runs: Path) -> dict:
    """Every step output in the cache -> (inode, mtime): a rewritten output is a new inode."""
    return {str(p.relative_to(runs)): (p.stat().st_ino, p.stat().st_mtime_ns)
            for p in (runs / "cache").glob("*/*") if not p.name.startswith(".")}


@pytest.mark.slow
def test_killed_run_resumes_and_redoes_nothing(dataset, reference_run, tmp_path):
    import psutil

    runs = tmp_path / "runs"
    p = cli(*run_args(dataset, runs), start_new_session=True)
    deadline = time.monotonic() + 300
    children = []
    while time.monotonic() < deadline and p.poll() is None:
        children = children or psutil.Process(p.pid).children(recursive=True)
        if list((runs / "cache").glob("*/lift-*.npz")):  # a finished step, the others still to come
            break
        time.sleep(0.02)
    assert p.poll() is None, "the run ended before it could be killed"
    os.kill(p.pid, signal.SIGKILL)  # the `egograph run` process; its workers exit with it
    p.communicate(timeout=60)
    gone, alive = psutil.wait_procs(children, timeout=30)
    assert not alive, "workers outlived the killed run"
    before = outputs_state(runs)
    assert before and not (runs / "latest" / "summary.json").exists()

    p = cli(*run_args(dataset, runs))
    out, err = p.communicate(timeout=600)
    assert p.returncode == 1, err
    after = outputs_state(runs)
    assert {k: after[k] for k in before} == before  # nothing finished was done again
    tasks = json.loads((runs / "latest" / "run.json").read_text())["tasks"]
    assert set(before) <= {t["output"] for t in tasks.values() if t["reused"]}
    assert len(after) > len(before)
    assert (runs / "latest" / "summary.json").read_bytes() == (reference_run / "summary.json").read_bytes()
    assert not math.isnan(json.loads((runs / "latest" / "summary.json").read_text())["evaluation"]["kf"]["l2_m"])


def test_a_task_reports_its_worker_process_and_its_peak_memory(tmp_path):
    """run.json's worker_pid and worker_max_rss_mb (tools/bench_run.py's memory per worker), also for
    a task that failed."""
    from egograph.steps.run import run_task

    res = run_task({"key": "lift/seq01", "stage": "lift", "out": str(tmp_path / "lift.npz"),
                    "log": str(tmp_path / "logs" / "lift.txt")})
    assert res["status"] == "failed" and res["worker_pid"] == os.getpid()
    assert 10 < res["worker_max_rss_mb"] < 1e6
