"""Glue between the stages: open a recording, lift its detections, run a tracker, evaluate.

The CLI and the benchmarks in ``tools/`` call these, so both run the same code.
"""

from __future__ import annotations

from pathlib import Path

from egograph.core.errors import InputError
from egograph.eval.loader import evaluate_loaded, load_sequence
from egograph.eval.report import EvalReport
from egograph.io.detections import read_detection_dir, write_results_dir
from egograph.io.recording import Recording
from egograph.steps.settings import EgographConfig


def open_recording(path: str | Path, cfg: EgographConfig, *, calibration: str | Path | None = None,
                   annotations: str | Path | None = None, sequence: str | None = None) -> Recording:
    return Recording.open(path, sequence=sequence, calibration=calibration, annotations=annotations,
                          invalid_poses=cfg.io.invalid_poses, depth_factor=cfg.io.depth_factor or None)


def n_instances(rec: Recording) -> int | None:
    from egograph.io.annotations import read_labels

    if rec.annotation_dir is None:
        return None
    return len(read_labels(rec.annotation_dir / "labels.csv"))


def load_detections(rec: Recording, spec: str | Path, cfg: EgographConfig) -> dict:
    """Per-frame detections from a folder or a set name the recording carries (``svoe``, ``mvpe``)."""
    return read_detection_dir(rec.detections_dir(str(spec)), rec.timestamps, box_format=cfg.io.box_format)


def lift(rec: Recording, spec: str | Path, cfg: EgographConfig, progress: bool = True):
    """Detections -> (Observations, LiftReport) with ``cfg.lift``."""
    from egograph.geometry.lift import lift_recording

    dets = load_detections(rec, spec, cfg)
    return lift_recording(rec, dets, cfg.lift, progress=progress, n_instances=n_instances(rec))


GRAPH_TRACKERS = ("graph", "graph-causal")


def tracker_names() -> list[str]:
    from egograph.track.baselines import TRACKERS

    return sorted([*TRACKERS, *GRAPH_TRACKERS])


def track_graph(rec: Recording, obs, cfg: EgographConfig, causal: bool = False, progress: bool = False):
    """The factor-graph tracker -> :class:`~egograph.core.types.TrackResult`, with negative
    evidence from the recording's depth (``cfg.graph.negative_evidence``) and the support test
    against its mesh (``cfg.graph.max_support_gap_m``)."""
    from egograph.track.graph import graph_tracker
    from egograph.track.negative import NegativeEvidence

    scene = None
    if cfg.graph.negative_evidence or cfg.graph.max_support_gap_m > 0:
        scene = NegativeEvidence(rec, obs, cfg.graph.negative, cfg.graph.score_threshold)
    negative = scene if cfg.graph.negative_evidence else None
    support = None
    if scene is not None and scene.scene is not None and cfg.graph.max_support_gap_m > 0:
        gap = cfg.graph.max_support_gap_m
        support = lambda xyz: scene.supported(xyz, gap)  # noqa: E731
    result = graph_tracker(obs, rec.timestamps, cfg.graph, causal=causal, negative=negative, support=support,
                           progress=progress)
    if negative is not None:
        result.metadata["negative_depth_frames_read"] = negative.n_frames_read
    return result


def track_graph_joint(rec: Recording, obs, cfg: EgographConfig, progress: bool = False, factors=None):
    """Offline graph tracker in joint mode (``--joint-poses``): the PV poses become variables of
    one graph with the refinement factors (``cfg.refine``) and the landmarks of the stands the
    tracker found; the tracker then runs again on the observations and poses so corrected
    (``cfg.joint.rounds`` times). Returns ``(TrackResult, JointPoses)``; ``obs`` must be lifted
    with ``rec``'s poses. ``factors``: the recording's RefinementGraph when already built (with
    ``refinement_factors(..., confirm_jumps_now=False)``)."""
    from egograph.poses.refine import world_corrections
    from egograph.track.joint import joint_poses, move_observations, stands_from_result, unmove_points, with_joint_poses

    result = track_graph(rec, obs, cfg, progress=progress)
    jp = None
    corrections = None
    for _ in range(max(1, cfg.joint.rounds)):
        stands = stands_from_result(result, cfg.joint.min_inliers)
        if corrections is not None:  # stands were found on moved observations: back to the reported frame
            for st in stands:
                st.world = unmove_points(st.world, st.frames, corrections)
        jp = joint_poses(rec, stands, cfg.refine, cfg.graph.noise, cfg.joint, progress=progress, factors=factors)
        factors = jp.factors
        corrections = world_corrections(rec, jp.pv_poses)
        result = track_graph(with_joint_poses(rec, jp), move_observations(obs, corrections), cfg, progress=progress)
    result.metadata["joint_poses"] = jp.report
    result.metadata["tracker"] = "graph (joint poses)"
    return result, jp


def regt_estimates(rec: Recording, ann, obs, cfg: EgographConfig, joint: bool = False, progress: bool = False):
    """``egograph regt``: re-estimated centres of the annotated intervals from the lifted boxes
    ``obs``; with ``joint`` the poses are first solved together with one landmark per
    interval (refinement factors + the boxes' inliers). Returns ``(estimates, JointPoses | None)``."""
    from egograph.poses.refine import world_corrections
    from egograph.track.joint import joint_poses, move_observations
    from egograph.track.regt import interval_stands, reestimate_centres

    jp = None
    if joint:
        stands = interval_stands(ann, obs, cfg.graph, cfg.joint.min_inliers)
        jp = joint_poses(rec, stands, cfg.refine, cfg.graph.noise, cfg.joint, progress=progress)
        obs = move_observations(obs, world_corrections(rec, jp.pv_poses))
    return reestimate_centres(ann, obs, cfg.graph, cfg.regt), jp


def track(rec: Recording, tracker: str, obs, cfg: EgographConfig) -> dict:
    """Run a named tracker on observations -> per-frame predictions {ts: [Prediction]}."""
    from egograph.track.baselines import TRACKERS

    if tracker in GRAPH_TRACKERS:
        return track_graph(rec, obs, cfg, causal=tracker == "graph-causal").per_frame
    if tracker not in TRACKERS:
        raise ValueError(f"unknown tracker {tracker!r}; available: {', '.join(tracker_names())}")
    return TRACKERS[tracker](obs, rec.timestamps, cfg.track)


def write_results(out: str | Path, rec: Recording, per_frame: dict) -> None:
    write_results_dir(out, per_frame, [int(t) for t in rec.timestamps])


def evaluate(rec: Recording, results_dir: str | Path) -> EvalReport:
    """IT3DEgo metrics of one results folder against the recording's annotations."""
    if rec.annotation_dir is None:
        raise InputError(rec.seq_dir, "no annotations found (labels.csv, 3d_center_annot.txt); pass --annotations DIR")
    seq = load_sequence(rec.seq_dir / "pv_pose.json", rec.annotation_dir / "3d_center_annot.txt", results_dir,
                        rec.annotation_dir / "labels.csv")
    result, intervals = evaluate_loaded(seq)
    report = EvalReport()
    report.add(rec.name, result, intervals, seq.labels, getattr(seq.predictions, "frames_without_file", 0))
    return report
