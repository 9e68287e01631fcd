"""The config system: YAML + dotted --set overrides into typed dataclasses, with clear errors."""

import pytest

from egograph.core.config import describe, load_config
from egograph.core.errors import ConfigError
from egograph.synth.config import SynthConfig


def test_yaml_and_overrides(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("frames: 100\nscene:\n  n_instances: 6\n")
    cfg = load_config(SynthConfig, p, ["scene.room_size=[5, 4, 2.5]", "pv.rgb=false", "ahat.alias_mm=999"])
    assert cfg.frames == 100 and cfg.scene.n_instances == 6
    assert cfg.scene.room_size == [5.0, 4.0, 2.5] and cfg.pv.rgb is False and cfg.ahat.alias_mm == 999.0
    assert cfg.wearer.walk_speed == SynthConfig().wearer.walk_speed  # untouched defaults stay
    docs = dict((k, d) for k, _, d in describe(cfg))
    assert "wrap" in docs["ahat.alias_mm"] and all(docs.values())  # every knob documented


@pytest.mark.parametrize("override, message", [
    ("scene.n_instance=3", "unknown key.*n_instance"),
    ("frames=many", "frames: expected an integer"),
    ("pv.rgb=2", "pv.rgb: expected true/false"),
    ("frames", "expected dotted.key=value"),
])
def test_bad_overrides(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config(SynthConfig, None, [override])


def test_bad_file_named(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("scene: [1, 2\n")
    with pytest.raises(ConfigError, match="bad.yaml: not valid YAML"):
        load_config(SynthConfig, p)
