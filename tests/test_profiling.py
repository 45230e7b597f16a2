"""The mapping profile of `bench map`: stage timers over a real mapper, and the blend's ceiling probe."""

import pytest
from test_mapping_online import views  # noqa: F401  (the fixture: two MuJoCo RGB-D views of office0)

from flightrecon import profiling
from flightrecon.config import MapperConfig
from flightrecon.mapping.mapper import OnlineMapper
from flightrecon.render.extension import load


def test_profile_counts_every_iteration_and_no_stage_is_negative(views):
    K, vs = views
    cfg = MapperConfig(backend="cpu", init_subsample=0.3, init_scale_by_resolution=False, k_new=3, k_replay=2,
                       prune_opacity=0.05)
    mapper = OnlineMapper(cfg, near=0.05, far=10.0, seed=0, device="cpu")
    with profiling.profiling() as prof:
        for rgb, depth, T in vs:
            mapper.add_frame(rgb, depth, K, T)
    assert not profiling.active()
    # each frame: k_new iterations on it, then k_replay iterations of one call each (frame 0 replays itself)
    assert prof.calls["render"] == prof.calls["backward"] == 2 * (3 + 2)
    assert prof.calls["view setup"] == 2 * (2 * (1 + 2))  # setup and write-back per call
    assert prof.calls["add_frame"] == prof.calls["densify"] == prof.calls["prune"] == 2
    assert prof.kernel["forward.evals"] >= prof.kernel["forward.blends"] > 0
    # the splat axes run inside render and inside the view setup's culling: each enclosing stage
    # knows the time spent inside it
    assert prof.inner["render"] > 0 and prof.inner["view setup"] > 0 and prof.inner["loss"] > 0
    assert prof.exclusive("render") < prof.seconds["render"]
    rows = profiling.breakdown(prof, frames=2)
    # exclusive times: a nested stage never takes more than the stage around it (timer resolution aside)
    assert all(r["share"] > -1e-3 for r in rows), rows
    assert sum(r["share"] for r in rows) == pytest.approx(1.0)
    names = {r["stage"] for r in rows}
    assert {"project", "bin and sort", "forward blend", "backward blend", "SSIM", "depth normals",
            "optimizer step", "densify", "prune"} <= names


def test_stage_is_a_no_op_outside_a_profile():
    with profiling.stage("render"):
        pass
    with profiling.profiling() as prof:
        with profiling.stage("render"):
            pass
        with profiling.profiling() as inner:  # a nested profile collects alone, then adds to the outer
            with profiling.stage("loss"):
                pass
            profiling.add_kernel("forward", lambda: {"evals": 7.0})
        with profiling.stage("render"):
            pass
    assert dict(inner.calls) == {"loss": 1} and dict(inner.kernel) == {"forward.evals": 7.0}
    assert dict(prof.calls) == {"render": 2, "loss": 1} and dict(prof.kernel) == {"forward.evals": 7.0}
    assert prof.seconds["loss"] == inner.seconds["loss"]


def test_blend_rates_by_hand():
    prof = profiling.StageProfile()
    prof.add_kernel("forward", {"blend_s": 0.5, "evals": 3e8, "blends": 1e8})
    ceiling = {"blend_per_s_thread": 2e8, "reject_per_s_thread": 4e8}
    r = profiling.blend_rates(prof, ceiling, threads=2)
    # 1 thread-second: 2e8 rejected at 4e8/s (0.5 s) and 1e8 blended at 2e8/s (0.5 s)
    assert r["evals_M_per_s_thread"] == pytest.approx(300.0)
    assert r["blends_M_per_s_thread"] == pytest.approx(100.0)
    assert r["of_ceiling"] == pytest.approx(1.0)
    assert r["useful_of_ceiling"] == pytest.approx(0.5)
    assert r["evals_per_blend"] == pytest.approx(3.0)


def test_ceiling_probe_runs_on_every_thread():
    ext = load()
    c = ext.blend_ceiling(0.04)  # raises if its tile wasted an evaluation or blended when it must not
    assert c["threads"] == ext.num_threads()
    assert c["blend_per_s_thread"] > 0 and c["reject_per_s_thread"] > 0


def test_flight_profile_summary_by_hand():
    """Shares of the loop's time per block, from two frames written out by hand: the mapping's stages
    replace t_map, and what add_frame did not time counts as the mapping's rest."""
    from flightrecon.flight_profile import MAP_COLUMNS, summary

    zero = dict.fromkeys(MAP_COLUMNS.values(), 0.0)
    rows = [{"frame": 0, "t_capture": 1.0, "t_map": 6.0, "t_select_update": 0.0, "t_plan": 1.0, "t_score": 2.0,
             "t_fly_sim": 0.0, **zero, "map_forward_blend": 2.0, "map_backward_blend": 3.0},
            {"frame": 1, "t_capture": 1.0, "t_map": 2.0, "t_select_update": 0.0, "t_plan": 0.0, "t_score": 1.0,
             "t_fly_sim": 0.0, **zero, "map_forward_blend": 1.0, "map_backward_blend": 1.0}]
    table = {r["stage"]: r for r in summary(rows, every=1)}
    # frame 0: 10 s in all, frame 1: 4 s; 14 s over both
    assert table["map: forward blend"]["s_per_frame"] == pytest.approx(1.5)
    assert table["map: forward blend"]["share all"] == pytest.approx(3.0 / 14.0)
    assert table["map: forward blend"]["share 0-0"] == pytest.approx(0.2)
    assert table["map: backward blend"]["share 1-1"] == pytest.approx(0.25)
    assert table["map: rest"]["share 0-0"] == pytest.approx(0.1)  # 6 s of mapping, 5 s of them in stages
    assert table["score"]["share all"] == pytest.approx(3.0 / 14.0)
    assert table["loop total"]["s_per_frame"] == pytest.approx(7.0)
    for block in ("all", "0-0", "1-1"):
        assert sum(r[f"share {block}"] for name, r in table.items() if name != "loop total") == pytest.approx(1.0)
