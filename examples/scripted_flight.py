"""Script a flight with FlightRecon's Python API: step the closed loop, look at the candidates the
selector weighs, render the map, evaluate the run (docs/python_api.md).

    python examples/scripted_flight.py [RUN_DIR]

Small settings (the demo scene at 80x60, 4 frames) so it runs in about a minute on 2 cores.
"""

import sys

import numpy as np

import flightrecon

SMALL = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
         "mapper.k_new=5", "mapper.k_replay=3", "budget.frames=4", "budget.initial_views=2",
         "evaluation.views=2", "evaluation.every=0", "output.record=false", "metrics.tsdf_voxel=0.05",
         "metrics.tsdf_truncation=0.15", "metrics.sample_points=5000"]


def main(run_dir: str) -> None:
    cfg = flightrecon.load_config("demo", SMALL)
    mission = flightrecon.Mission(cfg, run_dir, progress=False)

    # the first frames as the loop flies them; each step captures, maps, selects and flies
    for _ in range(2):
        row = mission.step()
        print(f"frame {row['frame']}: {row['n_splats']} splats, frame PSNR {row['frame_psnr']:.2f} dB")

    # what the selector sees now: the planner's feasible candidates and their scores
    feasible = [c for c in mission.plan_candidates() if c.feasible]
    scores = mission.score_candidates(feasible)
    best = np.argsort(scores)[::-1][:3]
    for i in best:
        c = feasible[i]
        print(f"candidate at {np.round(c.position, 2).tolist()} yaw {np.degrees(c.yaw):.0f} deg: "
              f"score {scores[i]:.1f}, path {c.length:.2f} m")

    while not mission.done:
        mission.step()
    metrics = mission.finish()
    print(f"{metrics['frames']} frames, flew {metrics['flight_distance_m']:.2f} m, "
          f"evaluation PSNR {metrics['eval']['psnr']:.2f} dB")

    # the saved map rendered where the drone is now
    gmap = flightrecon.load_map(f"{run_dir}/map.ply")
    T_wc = mission.flight.camera_pose()
    out = flightrecon.render_map(gmap, T_wc, mission.rig.K, cfg.camera.width, cfg.camera.height)
    print(f"map rendered at the last pose: {float((out.alpha > 0.5).float().mean()):.2f} of the pixels covered")

    scored = flightrecon.evaluate_run(run_dir)
    print(f"evaluate_run: PSNR {scored['psnr']:.2f} dB, depth L1 {scored['depth_l1_cm']:.2f} cm, "
          f"F-score {scored['fscore']:.3f}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "runs/scripted_flight")
