"""Joint mode (``--joint-poses``): the PV camera poses solved in one graph with the refinement
factors (``cfg.refine``) and the landmarks of still objects, then the estimate run again on the
corrected poses. Used by ``track --tracker graph`` and by ``regt``."""

from __future__ import annotations

import dataclasses

from egograph.core.types import TrackResult
from egograph.io.recording import Recording
from egograph.track.registry import graph_with_scene


def track_joint(rec: Recording, obs, cfg, progress: bool = False, factors=None) -> tuple[TrackResult, object]:
    """Offline graph tracker in joint mode: the tracker's stands become landmarks of the pose graph;
    the tracker then runs again on the observations and poses so corrected (``cfg.joint.rounds``
    times). Returns ``(TrackResult, JointPoses)``; ``obs`` must be lifted with ``rec``'s poses.
    ``factors``: the recording's RefinementGraph when already built (with
    ``refinement_factors(..., confirm_jumps_now=False)``)."""
    from egograph.poses.refine import world_corrections
    from egograph.track.joint import joint_poses, move_observations, stands_from_result, unmove_points, with_joint_poses

    result = graph_with_scene(rec, obs, cfg, progress=progress)
    jp = None
    corrections = None
    for _ in range(max(1, cfg.joint.rounds)):
        stands = stands_from_result(result, cfg.joint.min_inliers)
        if corrections is not None:  # stands were found on moved observations: back to the reported frame
            for st in stands:
                st.world = unmove_points(st.world, st.frames, corrections)
        # the detection noise the tracker fitted for this front-end (graph.noise.auto_scale)
        noise = dataclasses.replace(cfg.graph.noise, scale=result.metadata.get("noise_scale", cfg.graph.noise.scale))
        jp = joint_poses(rec, stands, cfg.refine, noise, cfg.joint, progress=progress, factors=factors)
        factors = jp.factors
        corrections = world_corrections(rec, jp.pv_poses)
        result = graph_with_scene(with_joint_poses(rec, jp), move_observations(obs, corrections), cfg,
                                  progress=progress)
    result.metadata["joint_poses"] = jp.report
    result.metadata["tracker"] = "graph (joint poses)"
    return result, jp


def regt_joint(rec: Recording, ann, obs, cfg, progress: bool = False):
    """Observations moved by the poses solved with one landmark per annotated interval ->
    ``(moved observations, JointPoses)``."""
    from egograph.poses.refine import world_corrections
    from egograph.track.joint import joint_poses, move_observations
    from egograph.track.regt import interval_stands

    stands = interval_stands(ann, obs, cfg.graph, cfg.joint.min_inliers)
    jp = joint_poses(rec, stands, cfg.refine, cfg.graph.noise, cfg.joint, progress=progress)
    return move_observations(obs, world_corrections(rec, jp.pv_poses)), jp


def write_joint_poses(rec: Recording, jp, cfg, out) -> None:
    """The jointly solved poses in the ``egograph refine`` output format."""
    from egograph.poses.refine import write_refined

    write_refined(jp.poses, out, rec, cfg.refine, {"mode": "joint (poses + object landmarks)", "joint": cfg.joint})
