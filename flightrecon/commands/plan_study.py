"""`flightrecon plan-study SCENARIO`: how kinematic limits, safety margin and library change what is reachable.

For the scenario's scene, the full candidate library is checked from representative free poses for
every combination of max velocity, max acceleration, safety margin, library and (optionally) max
yaw rate. It reports the
share of feasible candidates, durations, lengths, planning times and the share needing OMPL; with
--fly, the SE(3) controller flies some feasible trajectories in MuJoCo and the study adds the
tracking error, the minimum clearance of the body and contacts. Planning uses the ground-truth scene
(planner.use_ground_truth) so the study isolates the planner from mapping. Writes study.csv,
study.md and figures/plan_study.png.
"""

from __future__ import annotations

import argparse
import csv
import io
import itertools
import math
import statistics
import time
from pathlib import Path

import numpy as np

from flightrecon.control.trajectory import FlatState
from flightrecon.errors import ConfigError
from flightrecon.fileio import atomic_path, write_text
from flightrecon.planning.distance_field import DistanceField
from flightrecon.planning.feasibility import PlanningSettings, PlanningTimes, check_candidates
from flightrecon.planning.library import load_library
from flightrecon.planning.occupancy import FREE, OCCUPIED
from flightrecon.planning.poses import sample_free_poses, start_position, workspace_of
from flightrecon.scenario import load_config


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan-study", help="sweep planner limits, margin and library: feasibility, durations, tracking")
    p.add_argument("scenario", help="scenario TOML path or name in scenarios/")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value (repeatable)")
    p.add_argument("--vel", default="0.5,1.0,2.0", help="max velocities to sweep (m/s)")
    p.add_argument("--acc", default="1.0,2.0,4.0", help="max accelerations to sweep (m/s^2)")
    p.add_argument("--margin", default="0.05,0.1,0.2", help="safety margins to sweep (m)")
    p.add_argument("--yaw-rate", default="", help="max yaw rates to sweep (deg/s); default: the scenario's. "
                   "Turns of up to 180 deg often set the duration of these short moves")
    p.add_argument("--library", default="", help="comma-separated libraries ('default' or TOML paths); "
                   "default: the scenario's planner.library")
    p.add_argument("--poses", type=int, default=4, help="poses per combination (the take-off point first)")
    p.add_argument("--fly", type=int, default=2, help="feasible trajectories flown in MuJoCo per combination (0: none)")
    p.add_argument("--out", default=None, help="output folder (default: <output.run_root>/<scenario>/plan-study)")
    p.set_defaults(func=run)


def _floats(text: str, key: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ConfigError(f"plan-study --{key}: expected comma-separated numbers, got '{text}'") from None
    if not values:
        raise ConfigError(f"plan-study --{key}: no values given")
    return values


def run(args: argparse.Namespace) -> int:
    from flightrecon.scene.source import scene_from_config

    base = load_config(args.scenario, list(args.overrides) + ["planner.use_ground_truth=true"])
    vels, accs, margins = _floats(args.vel, "vel"), _floats(args.acc, "acc"), _floats(args.margin, "margin")
    yaw_rates = _floats(args.yaw_rate, "yaw-rate") if args.yaw_rate else [base.planner.max_yaw_rate_deg]
    libraries = [s.strip() for s in args.library.split(",") if s.strip()] or [base.planner.library]
    combos = list(itertools.product(libraries, yaw_rates, vels, accs, margins))
    # Validate every combination before the expensive part, so a bad value fails at once.
    cfgs = [load_config(args.scenario, list(args.overrides) + [
        "planner.use_ground_truth=true", f"planner.library={lib}", f"planner.max_yaw_rate_deg={w}",
        f"planner.max_vel={v}", f"planner.max_acc={a}", f"planner.safety_margin={m}"])
        for lib, w, v, a, m in combos]
    libs = {lib: load_library(lib) for lib in libraries}
    out = Path(args.out) if args.out else Path(base.output.run_root) / base.name / "plan-study"
    scene = scene_from_config(base.scene)
    ws = workspace_of(scene, base.planner.max_height)
    start = start_position(scene, base.sim.takeoff_height)
    print(f"plan-study: {scene.name}, {len(combos)} combinations x {args.poses} poses", flush=True)
    field = DistanceField.from_mesh(scene.trimesh, base.planner.voxel_size,
                                    ws + np.array([[-0.5], [0.5]]), free_seeds=start[None], signed=False)
    widest = base.drone.body_radius + max(margins) + 0.1
    poses, yaws = sample_free_poses(field, ws, max(args.poses - 1, 0), widest, seed=base.seed)
    poses, yaws = np.vstack([start, poses]), np.concatenate([[0.0], yaws])
    flyer = _Flyer(scene, base) if args.fly > 0 else None
    rows = []
    for (lib, w, v, a, m), cfg in zip(combos, cfgs):
        settings = PlanningSettings.from_config(cfg)
        durations, lengths, plan_ms, ompl, n_all, n_ok, reasons, flown = [], [], [], 0, 0, 0, {}, []
        for p, y in zip(poses, yaws):
            state = FlatState(p, np.zeros(3), np.zeros(3), float(y), 0.0)
            cand_p, cand_y = libs[lib].poses(p, float(y))
            target = np.where(field.distance(cand_p) > 0, FREE, OCCUPIED)
            times = PlanningTimes()
            t0 = time.perf_counter()
            res = check_candidates(state, cand_p, cand_y, field, target, ws, settings, times)
            plan_ms.append(1e3 * (time.perf_counter() - t0))
            ompl += times.n_ompl
            n_all += len(res)
            for r in res:
                reasons[r.reason] = reasons.get(r.reason, 0) + 1
            ok = [r for r in res if r.feasible]
            n_ok += len(ok)
            durations += [r.duration for r in ok]
            lengths += [r.length for r in ok]
            if flyer is not None and ok and len(flown) < args.fly:
                longest = max(ok, key=lambda r: r.length)
                flown.append(flyer.fly(cfg, p, float(y), longest.trajectory))
        row = {"library": lib, "max_yaw_rate_deg": w, "max_vel": v, "max_acc": a, "safety_margin": m,
               "share_feasible": n_ok / max(n_all, 1), "share_ompl": ompl / max(n_all, 1),
               "duration_median_s": _med(durations), "duration_max_s": max(durations, default=math.nan),
               "length_median_m": _med(lengths), "plan_ms_median": _med(plan_ms),
               "rejected": " ".join(f"{k}:{n}" for k, n in sorted(reasons.items()) if k != "feasible")}
        if flyer is not None:
            row.update({"flown": len(flown),
                        "tracking_err_max_m": max((f[0] for f in flown), default=math.nan),
                        "min_clearance_m": min((f[1] for f in flown), default=math.nan),
                        "contacts": sum(f[2] for f in flown)})
        rows.append(row)
        print(f"  {lib} yaw rate {w:g} vel {v:g} acc {a:g} margin {m:g}: {100 * row['share_feasible']:.0f}% feasible, "
              f"{row['plan_ms_median']:.0f} ms/library", flush=True)
    if flyer is not None:
        flyer.close()
    _write(out, rows, scene.name)
    print(f"plan-study: wrote {out / 'study.csv'}, {out / 'study.md'}, {out / 'figures' / 'plan_study.png'}")
    return 0


def _med(x: list[float]) -> float:
    return statistics.median(x) if x else math.nan


class _Flyer:
    """Flies trajectories from rest in one MuJoCo world; reports tracking error, clearance, contacts."""

    def __init__(self, scene, cfg):
        from flightrecon.sim.world import build_world

        self.world = build_world(scene, cfg)
        self.mesh = scene.trimesh

    def fly(self, cfg, position: np.ndarray, yaw: float, trajectory) -> tuple[float, float, int]:
        from flightrecon.sim.flight import Flight
        from flightrecon.sim.safety import ClearanceMonitor, FlightDiverged

        flight = Flight.from_world(self.world, cfg, ClearanceMonitor(self.mesh, cfg.drone.body_radius))
        flight.start(position, yaw)
        try:
            log = flight.fly(trajectory, extra_time=0.5)
        except FlightDiverged as exc:
            log = exc.log
        err = np.linalg.norm(log.positions - log.reference_positions, axis=1)
        return float(err.max()), float(np.nanmin(log["clearance"])), len(flight.log.events)

    def close(self) -> None:
        self.world = None


def _write(out: Path, rows: list[dict], scene_name: str) -> None:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=keys)
    writer.writeheader()
    writer.writerows(rows)
    write_text(out / "study.csv", buf.getvalue())
    md = [f"# Planner feasibility study: {scene_name}", "",
          "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        md.append("| " + " | ".join(f"{r[k]:.3g}" if isinstance(r.get(k), float) else str(r.get(k, ""))
                                    for k in keys) + " |")
    write_text(out / "study.md", "\n".join(md) + "\n")
    _figure(out / "figures" / "plan_study.png", rows, scene_name)


def _figure(path: Path, rows: list[dict], scene_name: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    flown = any("tracking_err_max_m" in r for r in rows)
    fig, axes = plt.subplots(1, 4 if flown else 3, figsize=(20 if flown else 15, 4.2))
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["library"], r["max_yaw_rate_deg"], r["max_vel"], r["max_acc"]), []).append(r)
    for (lib, w, v, a), rs in groups.items():
        rs = sorted(rs, key=lambda r: r["safety_margin"])
        label = (f"v {v:g}, a {a:g}" + (f", yaw {w:g}" if len({k[1] for k in groups}) > 1 else "")
                 + (f", {lib}" if len({k[0] for k in groups}) > 1 else ""))
        axes[0].plot([r["safety_margin"] for r in rs], [100 * r["share_feasible"] for r in rs], "o-", label=label)
        axes[1].plot([r["safety_margin"] for r in rs], [r["duration_median_s"] for r in rs], "o-", label=label)
        axes[2].plot([r["safety_margin"] for r in rs], [r["plan_ms_median"] for r in rs], "o-", label=label)
        if flown:
            axes[3].plot([r["safety_margin"] for r in rs], [100 * r["tracking_err_max_m"] for r in rs], "o-",
                         label=label)
    axes[0].set_ylabel("feasible candidates (%)")
    axes[1].set_ylabel("median trajectory duration (s)")
    axes[2].set_ylabel("library check (ms, median)")
    if flown:
        axes[3].set_ylabel("max tracking error when flown (cm)")
    for ax in axes:
        ax.set_xlabel("safety margin (m)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    fig.suptitle(f"Planner feasibility study: {scene_name}")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
