"""Scenario config: defaults are the paper's, bad keys and values name the key, round trip is exact."""

from pathlib import Path

import pytest

from flightrecon.config import SCENARIO_DIR, ScenarioConfig, to_toml
from flightrecon.errors import ConfigError
from flightrecon.scenario import load_config


def test_defaults_are_paper_parameters():
    cfg = load_config(None)
    assert cfg.mapper == ScenarioConfig().mapper  # the loaded defaults are the schema's
    assert (cfg.mapper.gamma, cfg.mapper.k_new, cfg.mapper.k_replay) == (0.05, 60, 40)
    assert (cfg.mapper.lambda_depth, cfg.mapper.lambda_distortion, cfg.mapper.lambda_normal) == (5.0, 1.0, 0.05)
    r = cfg.reliability
    assert (r.w_min, r.lambda_L, r.lambda_T, r.lambda_rD, r.lambda_rNr) == (0.1, 1.0, 1.2, 3.0, 0.15)
    assert (cfg.camera.width, cfg.camera.height, cfg.camera.hfov_deg) == (640, 480, 90.0)


@pytest.mark.parametrize("path", sorted(SCENARIO_DIR.rglob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_scenario_loads(path):
    cfg = load_config(path)
    assert cfg.name == path.stem


def test_unknown_key_names_the_dotted_key(tmp_path: Path):
    p = tmp_path / "bad.toml"
    p.write_text("[mapper]\nk_neww = 3\n")
    with pytest.raises(ConfigError, match=r"mapper\.k_neww"):
        load_config(p)


@pytest.mark.parametrize("override, key", [
    ("mapper.k_new=-1", "mapper.k_new"),
    ("camera.hfov_deg=200", "camera.hfov_deg"),
    ("reliability.measurement_prior='x'", "reliability.measurement_prior"),
    ("budget.frames=1.5", "budget.frames"),
    ("output.record=1", "output.record"),
    ("scene=3", "scene"),
])
def test_invalid_values_name_the_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_config(None, [override])


def test_missing_and_corrupt_files(tmp_path: Path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml")
    bad = tmp_path / "corrupt.toml"
    bad.write_text("[mapper\nk_new = ")
    with pytest.raises(ConfigError, match="corrupt.toml"):
        load_config(bad)


def test_overrides_and_round_trip(tmp_path: Path):
    cfg = load_config("demo", ["mapper.k_new=7", "scene.name=office3", "control.kp=[1.0, 2.0, 3.0]"])
    assert cfg.mapper.k_new == 7 and cfg.scene.name == "office3" and cfg.control.kp == [1.0, 2.0, 3.0]
    p = tmp_path / "resolved.toml"
    p.write_text(to_toml(cfg))
    assert load_config(p) == cfg


def test_selector_sections_round_trip_and_keys_of_the_older_layout_move_to_them(tmp_path):
    cfg = load_config("demo", ["reliability.w_min=0.2", "activegs.voxel=0.3"])
    text = to_toml(cfg)
    assert "[reliability]\nw_min = 0.2" in text and "\n[activegs]\nvoxel = 0.3" in text
    path = tmp_path / "run.toml"
    path.write_text(text)
    assert load_config(path) == cfg
    # a config.toml of an earlier run: [baselines] and the selector's method-specific keys
    old = load_config("demo", ["baselines.gaussmi_lambda_T=3.0", "baselines.fisherrf_lambda=0.5",
                               "selector.explore_range=4.0", "selector.gain_floor=0.0"])
    assert old.gaussmi.lambda_T == 3.0 and old.fisherrf.regularizer == 0.5
    assert old.explore.range == 4.0 and old.reliability.gain_floor == 0.0
    assert "baselines" not in to_toml(old)
    with pytest.raises(ConfigError, match="unknown config key 'baselines' "):
        load_config("demo", ["baselines.nope=1"])
    with pytest.raises(ConfigError, match=r"unknown config key 'reliabilty' \(valid: .*reliability"):
        load_config("demo", ["reliabilty.w_min=0.2"])
