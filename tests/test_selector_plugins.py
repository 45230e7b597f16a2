"""A view-selection method from another package: the example plug-in (examples/selector_plugin) is
installed as a user would (pip, its `flightrecon.selectors` entry point) and flown through the CLI,
its own config section validated and written with the run, its map column saved, its stopping
statistic and diagnosis used; a broken plug-in is reported by name and leaves the others working."""

import csv
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from flightrecon.active import registry
from flightrecon.active.protocol import Selector
from flightrecon.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "examples" / "selector_plugin"
SMALL = ["camera.width=64", "camera.height=48", "selector.scoring_width=32", "selector.scoring_height=24",
         "mapper.k_new=5", "mapper.k_replay=3", "budget.frames=3", "budget.initial_views=2",
         "evaluation.views=2", "evaluation.every=0"]


def _sets(overrides):
    return [a for o in overrides for a in ("--set", o)]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The example plug-in installed into its own folder, plus a broken plug-in's metadata beside it."""
    target = tmp_path_factory.mktemp("site")
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "-q",
                        "--target", str(target), str(PLUGIN)], capture_output=True, text=True,
                       cwd=tmp_path_factory.mktemp("build"))
    assert r.returncode == 0, r.stderr[-3000:]
    broken = target / "broken_selector-0.1.dist-info"
    broken.mkdir()
    (broken / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-selector\nVersion: 0.1\n")
    (broken / "entry_points.txt").write_text("[flightrecon.selectors]\nbroken = no_such_module:Broken\n")
    return target


def _cli(site: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}
    return subprocess.run([sys.executable, "-m", "flightrecon.cli", *args], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=900)


def test_plugin_is_listed_and_a_broken_one_is_named(site, tmp_path):
    r = _cli(site, tmp_path, "selectors")
    assert r.returncode == 0, r.stderr
    assert "unseen_view  [method]  (plug-in: unseen_view)" in r.stdout
    assert "section [unseen_view]: width=32, height=24, path_weight=0.05, seen_enough=3" in r.stdout
    assert "map columns: times_seen ()" in r.stdout
    assert "broken  [left out]  no_such_module:Broken: ModuleNotFoundError" in r.stdout
    assert "gaussmi2d  [method]" in r.stdout  # the built-ins are all still there


def test_plugin_section_is_validated_like_the_built_in_ones(site, tmp_path):
    r = _cli(site, tmp_path, "fly", "demo", *_sets(SMALL + ["selector.method=unseen_view", "unseen_view.nope=1"]))
    assert r.returncode == 2 and "unknown config key 'unseen_view.nope'" in r.stderr
    r = _cli(site, tmp_path, "fly", "demo", *_sets(SMALL + ["selector.method=unseen_view",
                                                            "unseen_view.path_weight=-1"]))
    assert r.returncode == 2 and "'unseen_view.path_weight': -1.0 is below the minimum 0.0" in r.stderr
    r = _cli(site, tmp_path, "fly", "demo", *_sets(SMALL + ["selector.method=broken"]))
    assert r.returncode == 2 and "unknown method 'broken'" in r.stderr and "no_such_module" in r.stderr


@pytest.mark.slow
def test_plugin_flies_three_frames_through_the_cli(site, tmp_path):
    overrides = SMALL + ["selector.method=unseen_view", "unseen_view.path_weight=0.1", "unseen_view.seen_enough=1",
                         "output.ply_extras=true"]
    r = _cli(site, tmp_path, "fly", "demo", *_sets(overrides), "--no-record", "--quiet", "--diagnose",
             "--out", "run")
    assert r.returncode == 0, r.stderr[-3000:]
    run = tmp_path / "run"
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["method"] == "unseen_view" and metrics["frames"] == 3
    config = (run / "config.toml").read_text()
    assert "[unseen_view]\nwidth = 32\nheight = 24\npath_weight = 0.1\nseen_enough = 1" in config
    header = (run / "map.ply").read_bytes().split(b"end_header")[0].decode()
    assert "comment flightrecon column times_seen scalar" in header and "property float col_times_seen" in header
    rows = list(csv.DictReader(io.StringIO((run / "frames.csv").read_text())))
    ema = [float(row["reliable_share_ema"]) for row in rows]
    assert len(ema) == 3 and all(0 <= e <= 1 for e in ema) and ema[-1] > 0  # its stopping statistic, smoothed
    assert "unseen_share" in (run / "diagnosis.csv").read_text().splitlines()[0]


class _NotASelector:
    name = "plain"


class _Named(Selector):
    name = "dummy_for_registry_test"

    def score(self, view, poses, lengths=None):
        return poses[:, 0, 3]


def test_register_refuses_what_would_break_the_loop_or_the_config():
    with pytest.raises(ConfigError, match="is not a subclass of flightrecon.Selector"):
        registry.register(_NotASelector)

    class Clash(_Named):
        name, section, settings = "clash_for_registry_test", "reliability", dict

    with pytest.raises(ConfigError, match=r"section \[reliability\] is already declared by selector 'gaussmi2d'"):
        registry.register(Clash)

    class Builtin(_Named):
        name, section, settings = "builtin_for_registry_test", "mapper", dict

    with pytest.raises(ConfigError, match="'mapper' is a built-in config section"):
        registry.register(Builtin)

    class Role(_Named):
        name, role = "role_for_registry_test", "winner"

    with pytest.raises(ConfigError, match="`role` 'winner' is not one of"):
        registry.register(Role)
    assert "clash_for_registry_test" not in registry.selectors()


def test_a_script_registers_its_own_selector(tmp_path):
    registry.register(_Named)
    from flightrecon.scenario import load_config

    cfg = load_config("demo", ["selector.method=dummy_for_registry_test"])
    sel = registry.make_selector(cfg)
    assert isinstance(sel, _Named) and sel.stopping_statistic(None) is None and sel.propose(None, None, 0, 0) is None
    assert registry.role_of("dummy_for_registry_test") == "method"
    assert not registry.proposes_own_candidates("dummy_for_registry_test")
    assert registry.proposes_own_candidates("activegs_native")
    assert registry.methods_with_role("method", "baseline", "floor")[:2] == ["gaussmi2d", "gaussmi2d_explore"]
    assert "gaussmi2d_now" not in registry.methods_with_role("method", "baseline", "floor")


@pytest.mark.slow
def test_sweep_and_report_take_the_plugin(site, tmp_path):
    tiny = SMALL + ["budget.frames=2", "metrics.tsdf_voxel=0.05", "metrics.tsdf_truncation=0.15",
                    "metrics.sample_points=5000"]
    r = _cli(site, tmp_path, "sweep", "--scenario", "demo", "--scenes", "room0", "--methods", "unseen_view",
             "random", "--seeds", "1", "--run-root", "runs", *_sets(tiny + ["output.record=false"]))
    assert r.returncode == 0, r.stderr[-3000:]
    report = tmp_path / "runs" / "demo" / "report"
    assert "| unseen_view |" in (report / "overall.md").read_text()
    assert "| random | all |" in (report / "paired_unseen_view.md").read_text()  # a plug-in is a method
