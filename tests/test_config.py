"""The config system: YAML + dotted --set overrides into typed dataclasses, every knob checked
against its declaration, one-line errors naming the file or override and the key."""

import dataclasses

import pytest

from egograph.core.config import Checked, Rule, check_config, describe, knob, load_config, to_yaml
from egograph.core.errors import ConfigError
from egograph.geometry.config import SUPPORT_GAP_M, LiftConfig
from egograph.steps.settings import EgographConfig
from egograph.synth.config import SynthConfig
from egograph.track.config import SCORE_THRESHOLD, BaselineConfig, GraphConfig


def message(cls, overrides=(), path=None) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(cls, path, list(overrides))
    text = str(info.value)
    assert "\n" not in text  # one line
    return text


def test_yaml_and_overrides(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("frames: 100\nscene:\n  n_instances: 6\n")
    cfg = load_config(SynthConfig, p, ["scene.room_size=[5, 4, 2.5]", "pv.rgb=false", "ahat.alias_mm=999"])
    assert cfg.frames == 100 and cfg.scene.n_instances == 6
    assert cfg.scene.room_size == [5.0, 4.0, 2.5] and cfg.pv.rgb is False and cfg.ahat.alias_mm == 999.0
    assert cfg.wearer.walk_speed == SynthConfig().wearer.walk_speed  # untouched defaults stay
    docs = dict((k, d) for k, _, d in describe(cfg))
    assert "wrap" in docs["ahat.alias_mm"] and all(docs.values())  # every knob documented


@pytest.mark.parametrize("override, expected", [
    ("lift.mode=bogus", "--set lift.mode=bogus: lift.mode must be one of robust, reference"),
    ("lift.shrink=0", "--set lift.shrink=0: lift.shrink must be in (0, 1]"),
    ("lift.max_range_m=0.1", "--set lift.max_range_m=0.1: lift.max_range_m must be > 0.1"),
    ("lift.shrink=.nan", "--set lift.shrink=.nan: lift.shrink must be a number, not NaN"),
    ("lift.n_candidates=0", "--set lift.n_candidates=0: lift.n_candidates must be >= 1"),
    ("io.box_format=xyzw", "--set io.box_format=xyzw: io.box_format must be one of xyxy, xywh"),
    ("graph.switches=gnc", "--set graph.switches=gnc: graph.switches must be one of switchable, dcs"),
    ("graph.noise.kernel=l2",
     "--set graph.noise.kernel=l2: graph.noise.kernel must be one of cauchy, huber, geman_mcclure, tukey, none"),
    ("graph.still_sigma_m=0", "--set graph.still_sigma_m=0: graph.still_sigma_m must be > 0"),
    ("graph.min_inlier_share=1.5", "--set graph.min_inlier_share=1.5: graph.min_inlier_share must be in [0, 1]"),
    ("graph.min_observations=0", "--set graph.min_observations=0: graph.min_observations must be >= 1"),
    ("graph.negative.stride=0", "--set graph.negative.stride=0: graph.negative.stride must be >= 1"),
    ("track.score_threshold=1.2", "--set track.score_threshold=1.2: track.score_threshold must be in [-1, 1]"),
    ("track.kf_measurement_noise_m=0",
     "--set track.kf_measurement_noise_m=0: track.kf_measurement_noise_m must be > 0"),
    ("joint.rounds=0", "--set joint.rounds=0: joint.rounds must be >= 1"),
    ("regt.audit_sigma=-1", "--set regt.audit_sigma=-1: regt.audit_sigma must be >= 0"),
    ("refine.point_stride=0", "--set refine.point_stride=0: refine.point_stride must be >= 1"),
    ("refine.colmap_image_scale=2", "--set refine.colmap_image_scale=2: refine.colmap_image_scale must be in (0, 1]"),
    ("refine.mesh_max_distance=[0.1,-1]",
     "--set refine.mesh_max_distance=[0.1,-1]: refine.mesh_max_distance items must be > 0"),
    ("refine.jump_confirm=[0.1]", "--set refine.jump_confirm=[0.1]: refine.jump_confirm must have 0 or 2 items"),
    ("lift={mode: x}", "--set lift={mode: x}: lift.mode must be one of robust, reference"),
    ("lift=3", "--set lift=3: lift must be a mapping (a section)"),
    ("lift.min_pixels=many", "--set lift.min_pixels=many: lift.min_pixels must be an integer"),
    ("graph.negative_evidence=2", "--set graph.negative_evidence=2: graph.negative_evidence must be true or false"),
])
def test_pipeline_knobs_checked(override, expected):
    assert message(EgographConfig, [override]) == expected


@pytest.mark.parametrize("override, expected", [
    ("scene.n_instance=3", "--set scene.n_instance=3: unknown key scene.n_instance (did you mean scene.n_instances?)"),
    ("frames=many", "--set frames=many: frames must be an integer"),
    ("pv.rgb=2", "--set pv.rgb=2: pv.rgb must be true or false"),
    ("frames", "--set frames: expected dotted.key=value"),
    ("=3", "--set =3: expected dotted.key=value"),
    ("scene.room_size=[1,2]", "--set scene.room_size=[1,2]: scene.room_size must have 3 items"),
    ("wearer.idle_time=[3,1]", "--set wearer.idle_time=[3,1]: wearer.idle_time must not decrease ([low, high])"),
    ("pv.png_compression=10", "--set pv.png_compression=10: pv.png_compression must be in [0, 9]"),
    ("detections.primary=x", "--set detections.primary=x: detections.primary must be one of svoe, mvpe"),
    ("detections.mvpe.detect_rate=2", "--set detections.mvpe.detect_rate=2: detections.mvpe.detect_rate must be in [0, 1]"),
    ("detections.svoe.true_score=[0.6,-0.1]",
     "--set detections.svoe.true_score=[0.6,-0.1]: detections.svoe.true_score must be [mean, std] with std >= 0"),
    ("sequence=a/b", "--set sequence=a/b: sequence must be a folder name (not empty, no path separator)"),
    ("sequence=no", "--set sequence=no: sequence must be a string (YAML reads that as False; quote it)"),
])
def test_synth_knobs_checked(override, expected):
    assert message(SynthConfig, [override]) == expected


@pytest.mark.parametrize("override, suggestion", [
    ("graph.kernel=huber", "graph.noise.kernel"),
    ("lift.score_threshold=0.5", "track.score_threshold"),
    ("lfit.mode=robust", "lift"),
    ("track.kf_reset=0.2", "track.kf_reset_distance_m"),
])
def test_unknown_key_suggests_the_nearest(override, suggestion):
    assert message(EgographConfig, [override]).endswith(f"(did you mean {suggestion}?)")


def test_unknown_key_without_a_near_one_lists_the_section():
    text = message(EgographConfig, ["track.zzz=1"])
    assert text == ("--set track.zzz=1: unknown key track.zzz; track has score_threshold, kf_reset_distance_m, "
                    "kf_process_noise, kf_measurement_noise_m, kf_initial_velocity_std")


def test_cross_knob_rule_names_both_keys():
    assert message(EgographConfig, ["refine.min_range=3"]) == (
        "--set refine.min_range=3: refine.min_range must be < refine.max_range "
        "(got refine.min_range=3.0, refine.max_range=2.5)")
    assert message(EgographConfig, ["graph.negative.agree_m=0.1"]).startswith(
        "--set graph.negative.agree_m=0.1: graph.negative.agree_m must be < graph.negative.margin_m")


def test_file_errors_name_file_line_and_value(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("lift:\n  mode: robust\n  shrink: 2\n")
    assert message(EgographConfig, path=p) == f"{p}:3: lift.shrink must be in (0, 1] (got 2.0)"
    p.write_text("graph:\n  chunk_s: 1\n  chunk: 2\n")
    assert message(EgographConfig, path=p) == f"{p}:3: unknown key graph.chunk (did you mean graph.chunk_s?)"
    p.write_text("scene: [1, 2\n")
    assert message(SynthConfig, path=p).startswith(f"{p}:2: not valid YAML")
    missing = message(SynthConfig, path=tmp_path / "none.yaml")
    assert missing.startswith(f"{tmp_path / 'none.yaml'}: config not found (no file {tmp_path / 'none.yaml'}")
    assert ("packaged configs: default, frontend-mvpe, frontend-svoe, synth/device-mvpe, synth/device-svoe, "
            "synth/device-tiny, "
            "synth/mvpe, synth/svoe, synth/tiny") in missing


def test_override_errors_are_not_blamed_on_the_file(tmp_path):
    p = tmp_path / "ok.yaml"
    p.write_text("lift:\n  shrink: 0.4\n")
    assert message(EgographConfig, ["lift.mode=x"], p) == "--set lift.mode=x: lift.mode must be one of robust, reference"
    assert message(EgographConfig, ["lift.bogus=1"], p).startswith("--set lift.bogus=1: unknown key lift.bogus")
    # a bad file value fixed by an override loads; one the override leaves alone is the file's
    p.write_text("lift:\n  shrink: 2\n  mode: nope\n")
    assert message(EgographConfig, ["lift.shrink=0.3"], p) == f"{p}:3: lift.mode must be one of robust, reference (got 'nope')"
    cfg = load_config(EgographConfig, p, ["lift.shrink=0.3", "lift.mode=reference"])
    assert (cfg.lift.shrink, cfg.lift.mode) == (0.3, "reference")
    # a whole section given by an override replaces the file's section and its blame
    p.write_text("lift:\n  shrink: 0.4\n")
    assert message(EgographConfig, ["lift={shrink: 0}"], p) == "--set lift={shrink: 0}: lift.shrink must be in (0, 1]"
    # a cross-knob rule is blamed on every source of its knobs, in the rule's key order
    p.write_text("refine:\n  max_range: 1.0\n")
    assert message(EgographConfig, ["refine.min_range=1.5"], p) == (
        f"--set refine.min_range=1.5, {p}:2: refine.min_range must be < refine.max_range "
        "(got refine.min_range=1.5, refine.max_range=1.0)")


def test_defaults_and_shipped_configs_pass_their_checks():
    for cls in (EgographConfig, SynthConfig):
        check_config(cls())
        for name in dataclasses.fields(cls):
            assert name.metadata.get("doc")


def test_every_knob_declares_a_rule_and_checks_directly():
    def walk(cfg, root=False):
        assert root or isinstance(cfg, Checked), type(cfg)  # EgographConfig only assembles sections
        for f in dataclasses.fields(cfg):
            v = getattr(cfg, f.name)
            if dataclasses.is_dataclass(v):
                walk(v)
            else:
                assert isinstance(f.metadata.get("rule"), Rule), f.name
    walk(EgographConfig(), root=True)
    walk(SynthConfig())
    with pytest.raises(ConfigError, match=r"^mode must be one of robust, reference \(got 'nope'\)$"):
        LiftConfig(mode="nope").check()
    with pytest.raises(ConfigError, match=r"^noise.kernel must be one of"):
        GraphConfig(noise=dataclasses.replace(GraphConfig().noise, kernel="l1")).check()


def test_result_knobs_unchanged():
    assert LiftConfig().result_knobs() == {
        "mode": "robust", "registration": "posed", "shrink": 0.5, "cluster_gap_m": 0.05, "min_cluster_share": 0.2,
        "min_pixels": 3, "surface_to_center_m": 0.03, "max_range_m": 5.5, "max_object_size_m": 0.45,
        "hand_reach_m": 0.8, "max_support_gap_m": 0.35, "use_mesh": True, "mesh_slack_m": 0.15, "n_candidates": 6,
    }


def test_shared_definitions():
    assert BaselineConfig().score_threshold == GraphConfig().score_threshold == SCORE_THRESHOLD == 0.6
    assert LiftConfig().max_support_gap_m == GraphConfig().max_support_gap_m == SUPPORT_GAP_M == 0.35


def test_knob_positional_and_rules():
    @dataclasses.dataclass
    class Small(Checked):
        a: int = knob(1, "a count")
        b: list[float] = knob([0.1, 0.2], "a range", min=0.0, length=2, ordered=True)
        c: str = knob("x", "a choice", choices=("x", "y"))

    assert load_config(Small, None, ["a=-5"]).a == -5  # no rule: any integer
    assert message(Small, ["b=[0.3,0.2]"]) == "--set b=[0.3,0.2]: b must not decrease ([low, high])"
    assert message(Small, ["c=z"]) == "--set c=z: c must be one of x, y"
    assert Rule(min=0.0, lt=1.0).problem(1.0) == "must be in [0, 1)"
    assert Rule(max=3).problem(4) == "must be <= 3"
    assert Rule(gt=0.0).problem(float("inf")) is None


@pytest.mark.parametrize("cls, overrides", [
    (EgographConfig, []),
    (EgographConfig, ["lift.mode=reference", "graph.noise.kernel=huber", "refine.jump_confirm=[]", "io.box_format=xywh",
                      "graph.score_threshold=0.55", "refine.mesh_max_distance=[0.2, 0.1]"]),
    (SynthConfig, ['sequence="yes"', "scene.room_size=[5, 4, 2.5]", "pv.rgb=false", "detections.primary=mvpe"]),
])
def test_to_yaml_round_trip(tmp_path, cls, overrides):
    cfg = load_config(cls, None, overrides)
    text = to_yaml(cfg)
    p = tmp_path / "shown.yaml"
    p.write_text(text)
    assert load_config(cls, p) == cfg
    lines = text.splitlines()
    # every knob line has its doc as a comment right above it
    for i, line in enumerate(lines):
        if not line.lstrip().startswith("#"):
            assert i > 0 and lines[i - 1].lstrip().startswith("#"), line
    assert "  # 'robust' (mesh-unwrapped" in text or cls is SynthConfig


def test_the_frontend_mvpe_configuration_is_the_default_with_stricter_graph_stands():
    """configs/frontend-mvpe.yaml (what `egograph detect --enroll mvpe` tells the user to track
    with) changes the graph's stand knobs only, so the paper's pipeline (lift, baselines, front-end)
    runs the same with either file."""
    from egograph.core.config import to_dict
    from egograph.core.resources import packaged_config_or_error

    preset = load_config(EgographConfig, packaged_config_or_error("frontend-mvpe"))
    default = load_config(EgographConfig, packaged_config_or_error("default"))
    assert (preset.graph.min_observations, preset.graph.min_inlier_share) == (6, pytest.approx(0.8))
    a, b = to_dict(preset), to_dict(default)
    changed = {(s, k) for s in a for k in a[s] if a[s][k] != b[s][k]}
    assert changed == {("graph", "min_observations"), ("graph", "min_inlier_share")}


def test_the_frontend_svoe_configuration_shares_one_operating_point_between_detector_and_trackers():
    """configs/frontend-svoe.yaml turns SVOE verification on, and the trackers' score threshold is the
    detector's own (a verified score is a probability: the paper's 0.6 on a cosine would drop
    detections the detector chose to keep); nothing else changes."""
    from egograph.core.config import to_dict
    from egograph.core.resources import packaged_config_or_error

    preset = load_config(EgographConfig, packaged_config_or_error("frontend-svoe"))
    default = load_config(EgographConfig, packaged_config_or_error("default"))
    assert preset.frontend.verify == "svoe"
    assert preset.graph.score_threshold == preset.track.score_threshold == preset.frontend.verify_threshold == 0.45
    a, b = to_dict(preset), to_dict(default)
    changed = {(s, k) for s in a for k in a[s] if a[s][k] != b[s][k]}
    assert changed == {("frontend", "verify"), ("frontend", "verify_threshold"), ("graph", "score_threshold"),
                       ("track", "score_threshold")}


@pytest.mark.parametrize("enroll, config, sets, hint", [
    ("svoe", "default", [], ""),
    ("mvpe", "default", [], "--config frontend-mvpe"),
    ("svoe", "frontend-svoe", [], "--config frontend-svoe"),
    ("svoe", "default", ["frontend.verify=svoe"], "--set graph.score_threshold=0.15"),
    ("mvpe", "default", ["frontend.verify=all", "frontend.verify_threshold=0.2"],
     "--config frontend-mvpe --set graph.score_threshold=0.2"),
    ("mvpe", "frontend-svoe", [], "--config frontend-mvpe"),      # frontend-svoe verifies SVOE only
])
def test_detect_names_the_tracking_configuration_that_keeps_its_detections(enroll, config, sets, hint):
    """`egograph detect` prints the `track` arguments for its detections: MVPE's stricter stands, and a
    score threshold no higher than the verification's operating point."""
    import argparse

    from egograph.cli.main import track_hint
    from egograph.core.resources import config_argument

    args = argparse.Namespace(enroll=enroll, config=config_argument(config), overrides=sets)
    cfg = load_config(EgographConfig, args.config, sets)
    assert track_hint(args, cfg) == hint
