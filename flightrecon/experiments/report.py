"""The paper's tables and figures from a sweep's run folders.

Tables (each as .md, .csv and .tex): `overall` (per method, mean over scenes and seeds with its
95% t-interval, as the paper's Table "Overall Evaluation Results", image metrics on all pixels and
on covered ones), `paired_<method>` for every method under study (selectors whose role is
"method": every other method's paired difference to it, over all scenes and per scene, with its 95%
interval: the same scenes and seeds are paired, and over all scenes the unit is the scene with its
seeds averaged; * where it excludes zero; with two flight-long endpoints: `psnr_auc`, the mean PSNR
over the frame budget, and `psnr_equal_time`, PSNR at the mission time the quickest compared run of
the scene needed for the whole budget),
`per_scene` (PSNR, D-L1, F-score per method and scene, mean and interval over seeds),
`efficiency` (per-candidate evaluation time, selector update time, model size), `ranking` (methods ranked at each in-flight
evaluation over the runs every method finished), `safety` (per method: flights that went inside their own
planner.safety_margin after take-off, in how many frames, the lowest clearance, flights with
contacts), and `summary.md` (what is compared, the run counts,
and whether the ranking at 2/3 of the budget equals the final one).
Per-candidate time = total scoring time / total feasible candidates scored, from frames.csv
(t_score, n_feasible) over the steps that scored more than one candidate.

Figures (PNG): quality over collected frames (PSNR and depth L1 of the evaluation views, which the
loop records every `evaluation.every` frames; mean with min-max spread across seeds, averaged over
scenes; mesh accuracy and completion from the map snapshots saved at those frames, scored after the flight by
`evaluate_run`), per-candidate time over frames, quality versus
per-candidate time labelled with model size, and novel-view grids (color, depth, normal) of the
first scene's first seed annotated with PSNR, depth L1 and mean normal angle error.
"""

from __future__ import annotations

import csv
import io
import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from flightrecon import provenance, run_folder
from flightrecon.active.registry import proposes_own_candidates, role_of
from flightrecon.evaluation.intervals import Interval, mean_interval, paired_difference
from flightrecon.config import PlannerConfig, read_toml
from flightrecon.fileio import atomic_path, write_text
from flightrecon.metric_defs import METRICS, mean_defined, select
from flightrecon.sim.safety import MarginRecord

# the metrics of each table and figure; labels, units, directions and decimals are metric_defs'
OVERALL = select("psnr", "psnr_covered", "covered_share", "ssim", "ssim_covered", "lpips", "depth_l1_cm",
                 "depth_l1_cm_covered", "accuracy_cm", "completion_cm", "chamfer_cm", "fscore")
PER_SCENE = select("psnr", "depth_l1_cm", "fscore")
SNAPSHOT = select("accuracy_cm", "completion_cm")  # mesh metrics of the in-flight map snapshots
RANKED = select("psnr", "depth_l1_cm", "fscore")
OVER_FRAMES_FIGURE = select("psnr", "depth_l1_cm") + SNAPSHOT
SHARED_PIPELINE = ("Every method here flies with the same 2DGS mapper, planner, candidate library, "
                   "simulator and evaluation: only the view-selection criterion differs. The paper ran "
                   "GauSS-MI and FisherRF on a 3DGS pipeline and ActiveGS with its own planner, so its "
                   "comparison also mixes in those differences; this one isolates the criterion.")
PAIRED = select("psnr", "psnr_covered", "depth_l1_cm", "completion_cm", "fscore", "psnr_auc", "psnr_equal_time")


def _read_frames(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _num(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def collect(run_dirs: list[Path]) -> list[dict]:
    """One record per finished run: its identity, eval.json, efficiency and per-frame series."""
    recs = []
    for d in run_dirs:
        d = Path(d)
        if not (d / run_folder.EVAL).is_file():
            continue
        ev = json.loads((d / run_folder.EVAL).read_text())
        met = json.loads((d / run_folder.METRICS).read_text())
        rows = _read_frames(d / run_folder.FRAMES)
        scored = [(_num(r["t_score"]), _num(r["n_feasible"])) for r in rows if _num(r.get("n_feasible")) > 1]
        n_cand = sum(n for _, n in scored)
        series = {k: np.array([_num(r.get(k)) for r in rows]) for k in
                  ("eval_psnr", "eval_depth_l1_cm", "t_score", "n_feasible", "sim_time")}
        if len(rows):
            series["eval_psnr"][-1] = _num(ev.get("psnr"))  # the final evaluation is the last frame's
        over = _read_frames(d / run_folder.OVER_FRAMES) if (d / run_folder.OVER_FRAMES).is_file() else []
        for m in SNAPSHOT:
            series[f"eval_{m.key}"] = _snapshot_series(over, len(rows), ev, m.key)
        recs.append({
            "margin": _margin_record(d, rows), "contacts": met.get("contacts", 0),
            "dir": d, "scene": d.parent.parent.name, "method": met["method"], "seed": met["seed"], **ev,
            "code_states": provenance.code_states(d), "cpus": provenance.cpus(d),
            "ms_per_candidate": 1000 * sum(t for t, _ in scored) / n_cand if n_cand else math.nan,
            "ms_update": 1000 * met["mean_times_s"].get("t_select_update", math.nan),
            "s_per_frame": met["wall_time_s"] / max(1, met["frames"]), "frames": met["frames"],
            "series": series, "checkpoints": _checkpoints(over, len(rows), ev),
            "psnr_auc": psnr_auc(series["eval_psnr"]),
        })
    add_equal_time_psnr(recs)
    return recs


def _margin_record(run_dir: Path, rows: list[dict]) -> MarginRecord:
    """The run's lowest clearances against the safety margin it flew with (its config.toml)."""
    planner = read_toml(run_dir / run_folder.CONFIG, "run config").get("planner", {})
    margin = float(planner.get("safety_margin", PlannerConfig.safety_margin))
    return MarginRecord.of([int(r["frame"]) for r in rows], [_num(r.get("min_clearance")) for r in rows], margin)


def psnr_auc(eval_psnr: np.ndarray) -> float:
    """Mean PSNR over the frame budget: the trapezoid area under PSNR over frames, between the first
    and the last evaluated frame, divided by their distance (NaN with fewer than two evaluations)."""
    frames = np.flatnonzero(np.isfinite(eval_psnr))
    if len(frames) < 2:
        return math.nan
    y = eval_psnr[frames]
    return float(np.sum((y[1:] + y[:-1]) * np.diff(frames)) / 2 / (frames[-1] - frames[0]))


def add_equal_time_psnr(recs: list[dict]) -> None:
    """Set each record's `psnr_equal_time`: its PSNR at the mission time T by which the quickest
    run of its scene (any method, any seed) finished the frame budget, linear between its
    evaluations in mission time (`sim_time`); NaN for a run never evaluated at or before T."""
    ends: dict[str, float] = {}
    for r in recs:
        t = r["series"]["sim_time"]
        if len(t) and math.isfinite(t[-1]):
            ends[r["scene"]] = min(ends.get(r["scene"], math.inf), float(t[-1]))
    for r in recs:
        y, t = r["series"]["eval_psnr"], r["series"]["sim_time"]
        ok = np.isfinite(y) & np.isfinite(t)
        T = ends.get(r["scene"], math.nan)
        r["psnr_equal_time"] = (float(np.interp(T, t[ok], y[ok])) if ok.any() and t[ok][0] <= T
                                else math.nan)


def _snapshot_series(over: list[dict], n_frames: int, final: dict, key: str) -> np.ndarray:
    """One mesh metric (cm) per frame: the in-flight snapshots' (rows of eval_over_frames.csv), the
    final map's at the last frame, NaN elsewhere."""
    out = np.full(n_frames, math.nan)
    for r in over:
        if int(r["frame"]) < n_frames:
            out[int(r["frame"])] = _num(r[key])
    if n_frames:
        out[-1] = _num(final.get(key))
    return out


def _checkpoints(over: list[dict], n_frames: int, final: dict) -> dict[int, dict[str, float]]:
    """{frame: {metric: value}} of the ranked metrics at every in-flight evaluation (rows of
    eval_over_frames.csv) and at the end."""
    out = {int(r["frame"]): {m.key: _num(r.get(m.key)) for m in RANKED} for r in over}
    if n_frames:
        out[n_frames - 1] = {m.key: _num(final.get(m.key)) for m in RANKED}
    return out


@dataclass(frozen=True)
class RankingCheck:
    """Methods ranked at each evaluation over the runs every method finished; `same[label]` says
    whether the ranking at frame `early` (the evaluation nearest 2/3 of the budget) equals the final one."""
    rows: list[list[str]]
    same: dict[str, bool]
    early: int
    end: int
    runs: int


def ranking_over_frames(recs: list[dict]) -> RankingCheck | None:
    """Rank the methods by their mean over the (scene, seed) runs that every method finished, at each
    in-flight evaluation and at the end (frames counted from 1); None without such runs."""
    methods = _methods(recs)
    if not methods:
        return None
    keys = set.intersection(*({(r["scene"], r["seed"]) for r in recs if r["method"] == m} for m in methods))
    runs = [r for r in recs if (r["scene"], r["seed"]) in keys]
    if not runs:
        return None
    frames = sorted(set.intersection(*(set(r["checkpoints"]) for r in runs)) - {0})
    end = frames[-1]
    early = min(frames[:-1] or frames, key=lambda f: abs(f + 1 - 2 * (end + 1) / 3))
    rows, order = [], {}
    for metric in RANKED:
        for f in frames:
            means = {m: _mean(r["checkpoints"][f][metric.key] for r in runs if r["method"] == m) for m in methods}
            order[metric, f] = sorted(methods, key=lambda m: metric.sort_key(means[m]))
            rows.append([metric.label, str(f + 1),
                         " > ".join(f"{m} ({metric.format(means[m])})" for m in order[metric, f])])
    same = {metric.label: order[metric, early] == order[metric, end] for metric in RANKED}
    return RankingCheck(rows, same, early + 1, end + 1, len(keys))


def _mean(vals) -> float:
    return mean_defined(_num(a) for a in vals)


def _fmt(v: float, digits: int) -> str:
    return "n/a" if math.isnan(v) else f"{v:.{digits}f}"


def _methods(recs: list[dict]) -> list[str]:
    """The methods of the runs: those under study (role "method") first, then the others, by name."""
    return sorted({r["method"] for r in recs}, key=lambda m: (role_of(m) != "method", m))


def code_states(recs: list[dict]) -> dict[str, int]:
    """{code state: runs that ran it (a run resumed across a code change counts for each)}."""
    counts: dict[str, int] = {}
    for r in recs:
        for state in r["code_states"]:
            counts[state] = counts.get(state, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: -kv[1]))


def _code_note(recs: list[dict]) -> str:
    """The caption's statement of the code its runs were flown with: loud when they mix states."""
    states = code_states(recs)
    if not states:
        return "no finished runs"
    if list(states) == [provenance.UNSTAMPED]:
        return (f"CODE NOT RECORDED: these {len(recs)} runs predate run stamps, so one table may mix code "
                "states (summary.md)")
    if len(states) > 1 or provenance.UNSTAMPED in states or any(len(r["code_states"]) > 1 for r in recs):
        return (f"MIXED CODE: these runs were flown with {len(states)} code states "
                f"({', '.join(f'{k}: {v} run(s)' for k, v in states.items())}; summary.md lists them)")
    return f"all runs flown at {next(iter(states))}"


def _scene_means(recs: list[dict], method: str, key: str) -> list[float]:
    """One value per scene: the method's mean over that scene's seeds (the unit of the intervals)."""
    by_scene: dict[str, list[float]] = {}
    for r in recs:
        if r["method"] == method:
            by_scene.setdefault(r["scene"], []).append(_num(r.get(key)))
    return [_mean(v) for v in by_scene.values()]


def _write_table(out: Path, name: str, header: list[str], rows: list[list[str]], caption: str) -> list[Path]:
    md = "| " + " | ".join(header) + " |\n|" + "---|" * len(header) + "\n"
    md += "".join("| " + " | ".join(r) + " |\n" for r in rows)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(header)
    w.writerows(rows)
    esc = lambda s: s.replace("_", r"\_").replace("%", r"\%")  # noqa: E731
    tex = ("\\begin{table}[t]\n\\centering\n\\caption{" + esc(caption) + "}\n\\begin{tabular}{l"
           + "c" * (len(header) - 1) + "}\n\\toprule\n" + " & ".join(esc(h) for h in header) + " \\\\\n\\midrule\n"
           + "".join(" & ".join(esc(c) for c in r) + " \\\\\n" for r in rows)
           + "\\bottomrule\n\\end{tabular}\n\\end{table}\n")
    paths = [out / f"{name}.md", out / f"{name}.csv", out / f"{name}.tex"]
    for p, text in zip(paths, (f"**{caption}**\n\n" + md, buf.getvalue(), tex)):
        write_text(p, text)
    return paths


def _by_run(recs: list[dict], method: str, key: str, scene: str | None = None) -> dict:
    """{(scene, seed): value} of one method's runs (one scene's, if given)."""
    return {(r["scene"], r["seed"]): _num(r.get(key)) for r in recs
            if r["method"] == method and (scene is None or r["scene"] == scene)}


ALL_UNITS = "all"  # over every scene folder: a variant (<scene>.v<K>) is a unit of its own
ALL_SCENES = "all, by scene"  # variants of one scene averaged first: the scene is the unit


def paired_interval(recs: list[dict], method: str, ours: str, key: str, row: str) -> Interval:
    """Over all scene folders the unit is the folder (its seeds averaged); over scenes, the scene
    (its variants and seeds averaged); within one scene folder, the seed."""
    unit = {ALL_UNITS: lambda k: k[0], ALL_SCENES: lambda k: run_folder.base_scene(k[0])}.get(row)
    scene = None if row in (ALL_UNITS, ALL_SCENES) else row
    return paired_difference(_by_run(recs, method, key, scene), _by_run(recs, ours, key, scene), unit=unit)


def _paired_cell(iv: Interval, digits: int) -> str:
    return iv.format(digits) + ("*" if iv.excludes_zero() else "")


def write_tables(recs: list[dict], out: Path, failed: dict[str, str] | None = None) -> list[Path]:
    """Every table, and summary.md (which lists `failed`: run folder -> why its flight stopped)."""
    out.mkdir(parents=True, exist_ok=True)
    methods = _methods(recs)
    scenes = sorted({r["scene"] for r in recs})
    seeds = sorted({r["seed"] for r in recs})
    code = _code_note(recs)
    note = f"{len(scenes)} scene(s), {len(seeds)} seed(s); {code}"
    rows = []
    for m in methods:
        rows.append([m] + [mean_interval(_scene_means(recs, m, k.key)).format(k.decimals) for k in OVERALL])
    paths = _write_table(out, "overall", ["Method"] + [k.heading for k in OVERALL], rows,
                         f"Overall evaluation results (mean over scenes ± 95% t-interval with the scene as the "
                         f"unit: each scene's seeds are averaged first; {note}; 'cov.': on pixels the map "
                         "covers, alpha >= 0.5)")
    variants = any(run_folder.base_scene(s) != s for s in scenes)
    summary_rows = [ALL_UNITS, ALL_SCENES] if variants else [ALL_UNITS]
    for ours in [m for m in methods if role_of(m) == "method"]:
        rows = []
        for m in [m for m in methods if m != ours]:
            for row in summary_rows + scenes:
                ivs = [paired_interval(recs, m, ours, k.key, row) for k in PAIRED]
                rows.append([m, row, str(ivs[0].n)] + [_paired_cell(iv, k.decimals) for iv, k in zip(ivs, PAIRED)])
        by_scene = (f"; '{ALL_SCENES}': the variants of each scene averaged first, 95% interval over scenes"
                    if variants else "")
        paths += _write_table(out, f"paired_{ours}",
                              ["Method", "Scene", "Units"] + [k.heading for k in PAIRED], rows,
                              f"Paired difference to {ours} (method - {ours} on the same scenes and seeds; "
                              f"'{ALL_UNITS}': mean over scene folders of the seed-averaged difference, 95% "
                              f"interval over them{by_scene}; per scene folder: over seeds; 'Units': the "
                              f"units behind the {PAIRED[0].heading} interval; * excludes zero; {note})")
    rows = []
    for m in methods:
        for k in PER_SCENE:
            rows.append([m, k.heading] + [mean_interval(_by_run(recs, m, k.key, s).values()).format(k.decimals)
                                          for s in scenes])
    paths += _write_table(out, "per_scene", ["Method", "Metric"] + scenes, rows,
                          f"Per-scene evaluation results (mean ± 95% interval with the seed as the unit, over "
                          f"{len(seeds)} seed(s); {code})")
    rows = []
    for m in methods:
        mine = [r for r in recs if r["method"] == m]
        rows.append([m, _fmt(_mean(r["ms_per_candidate"] for r in mine), 2),
                     _fmt(_mean(r["ms_update"] for r in mine), 1), _fmt(_mean(r["model_mb"] for r in mine), 2),
                     _fmt(_mean(r["s_per_frame"] for r in mine), 2)])
    paths += _write_table(out, "efficiency", ["Method", "Per-candidate [ms]", "Selector update [ms]",
                                              "Model [MB]", "Wall time per frame [s]"], rows,
                          f"Efficiency (mean over the runs of {note}; on the CPUs summary.md lists)")
    paths += _write_safety_table(recs, out, note)
    check = ranking_over_frames(recs)
    if check:
        paths += _write_table(out, "ranking", ["Metric", "Frames", "Ranking (best first, mean)"], check.rows,
                              f"Ranking over collected frames, over the {check.runs} (scene, seed) runs "
                              f"every method finished; {code}")
    paths.append(_write_summary(out, recs, check, failed or {}))
    return paths


def safety_cells(recs: list[dict]) -> list[str]:
    """Of these runs: how many went inside their own safety margin (frames.csv, take-off excluded),
    in how many frames, how close the closest came, and how many touched the scene."""
    lows = [r["margin"].lowest for r in recs if not math.isnan(r["margin"].lowest)]
    return [str(sum(not r["margin"].kept for r in recs)), str(sum(len(r["margin"].breach_frames) for r in recs)),
            _fmt(min(lows), 3) if lows else "n/a", str(sum(r["contacts"] > 0 for r in recs))]


def _write_safety_table(recs: list[dict], out: Path, note: str) -> list[Path]:
    """Per method: its runs and their `safety_cells`."""
    rows = []
    for m in _methods(recs):
        mine = [r for r in recs if r["method"] == m]
        rows.append([m, str(len(mine))] + safety_cells(mine))
    return _write_table(out, "safety", ["Method", "Runs", "Runs below margin", "Frames below margin",
                                        "Lowest clearance [m]", "Runs with contacts"], rows,
                        f"Safety: flights that went inside their planner.safety_margin after take-off, and "
                        f"contacts with the scene ({note})")


def _write_summary(out: Path, recs: list[dict], check: RankingCheck | None, failed: dict[str, str]) -> Path:
    """What the tables compare, how many runs they hold (and which flights failed, why), and whether
    the budget settles the ranking."""
    lines = ["# Sweep summary", "", SHARED_PIPELINE, ""]
    own = sorted({r["method"] for r in recs if proposes_own_candidates(r["method"])})
    if own:
        lines += [f"Except for the candidates: {', '.join(own)} choose among their own (docs/baselines.md), "
                  "which the same planner checks.", ""]
    states = code_states(recs)
    if len(states) > 1 or provenance.UNSTAMPED in states:
        lines += ["**MIXED CODE: the tables mix runs flown with different code, or with code no run recorded; "
                  "their differences may come from the code, not only from the methods.**", ""]
    lines.append("Code states (commit, +dirty with a hash of the uncommitted changes) and the runs flown with each:")
    lines += [f"- {k}: {v} run(s)" for k, v in states.items()]
    across = [str(r["dir"]) for r in recs if len(r["code_states"]) > 1]
    if across:
        lines.append(f"- resumed across a code change: {', '.join(across)}")
    cpus = sorted({c for r in recs for c in r["cpus"]})
    lines += ["", f"CPUs: {', '.join(cpus)}", ""]
    for m in _methods(recs):
        mine = [r for r in recs if r["method"] == m]
        lines.append(f"- {m}: {len(mine)} finished run(s) on {len({r['scene'] for r in mine})} scene(s)")
    breached = [r for r in recs if not r["margin"].kept]
    lines.append(f"- safety margin: {len(breached)} of {len(recs)} finished run(s) went inside it, "
                 f"{sum(r['contacts'] > 0 for r in recs)} touched the scene (safety.md)")
    lines.append("")
    if failed:
        lines.append(f"{len(failed)} flight(s) stopped with an error and are in no table:")
        lines += [f"- {d}: {why}" for d, why in sorted(failed.items())]
        lines.append("")
    if check:
        verdicts = ", ".join(f"{k} {'same' if v else 'differs'}" for k, v in check.same.items())
        lines.append(f"Ranking at frame {check.early} against the end (frame {check.end}), over the {check.runs} "
                     f"(scene, seed) runs every method finished: {verdicts} (ranking.md).")
    else:
        lines.append("No (scene, seed) has a finished run of every method yet: no ranking over frames.")
    path = out / "summary.md"
    write_text(path, "\n".join(lines) + "\n")
    return path


def _curve(recs: list[dict], key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frames, mean, min, max across seeds of the scene-averaged series (NaN rows dropped)."""
    by_seed: dict = {}
    for r in recs:
        by_seed.setdefault(r["seed"], []).append(r["series"][key])
    n = min(len(s) for ss in by_seed.values() for s in ss)
    with warnings.catch_warnings():  # frames without an evaluation are all-NaN columns
        warnings.simplefilter("ignore", RuntimeWarning)
        per_seed = np.array([np.nanmean(np.stack([s[:n] for s in ss]), 0) for ss in by_seed.values()])
    frames = np.arange(n)
    ok = np.isfinite(per_seed).all(0)
    return frames[ok], per_seed.mean(0)[ok], per_seed.min(0)[ok], per_seed.max(0)[ok]


def write_figures(recs: list[dict], out: Path) -> list[Path]:
    """The report's figures (none while no run has finished)."""
    if not recs:
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    methods = _methods(recs)
    paths = []

    fig, axes = plt.subplots(1, len(OVER_FRAMES_FIGURE), figsize=(18, 3.6))
    for ax, metric in zip(axes, OVER_FRAMES_FIGURE):
        for m in methods:
            f, mean, lo, hi = _curve([r for r in recs if r["method"] == m], f"eval_{metric.key}")
            ax.plot(f + 1, mean, marker="o", ms=3, label=m)
            ax.fill_between(f + 1, lo, hi, alpha=0.2)
        ax.set_xlabel("collected frames")
        ax.set_ylabel(metric.heading)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Evaluation-view quality over collected frames (mean, min-max across seeds)", fontsize=9)
    paths.append(_save(fig, out / "quality_over_frames.png", plt))

    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    positive = False
    for m in methods:
        mine = [r for r in recs if r["method"] == m]
        n = min(len(r["series"]["t_score"]) for r in mine)
        with warnings.catch_warnings():  # steps where no method scored are all-NaN columns
            warnings.simplefilter("ignore", RuntimeWarning)
            ms = np.nanmean(np.stack([1000 * r["series"]["t_score"][:n] / np.where(r["series"]["n_feasible"][:n] > 1,
                                                                                 r["series"]["n_feasible"][:n], np.nan)
                                      for r in mine]), 0)
        ok = np.isfinite(ms) & (ms > 0)
        positive |= bool(ok.any())
        ax.plot(np.arange(n)[ok] + 1, ms[ok], marker="o", ms=3, label=m)
    ax.set_xlabel("collected frames")
    ax.set_ylabel("per-candidate evaluation [ms]")
    if positive:
        ax.set_yscale("log")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    paths.append(_save(fig, out / "candidate_time_over_frames.png", plt))

    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    xs = []
    for m in methods:
        mine = [r for r in recs if r["method"] == m]
        x, y, mb = (_mean(r[k] for r in mine) for k in ("ms_per_candidate", "psnr", "model_mb"))
        xs.append(x)
        ax.scatter([x], [y], s=60)
        ax.annotate(f"{m}\n{mb:.2f} MB", (x, y), fontsize=8, xytext=(5, 5), textcoords="offset points")
    ax.set_xlabel("per-candidate evaluation [ms]")
    ax.set_ylabel(METRICS["psnr"].heading)
    if all(np.isfinite(x) and x > 0 for x in xs):
        ax.set_xscale("log")
    ax.grid(alpha=0.3)
    paths.append(_save(fig, out / "quality_vs_time.png", plt))

    paths.append(_novel_view_grid(recs, methods, out / "novel_views.png", plt))
    return paths


def _novel_view_grid(recs: list[dict], methods: list[str], path: Path, plt) -> Path:
    scene = sorted({r["scene"] for r in recs})[0]
    rows = []
    for m in methods:
        mine = sorted((r for r in recs if r["method"] == m and r["scene"] == scene), key=lambda r: r["seed"])
        if mine and (mine[0]["dir"] / run_folder.NOVEL_VIEW).is_file():
            rows.append((m, dict(np.load(mine[0]["dir"] / run_folder.NOVEL_VIEW))))
    fig, axes = plt.subplots(len(rows) + 1, 3, figsize=(9, 2.4 * (len(rows) + 1)), squeeze=False)
    if rows:
        gt = rows[0][1]
        vmax = float(np.nanmax(gt["gt_depth"])) or 1.0
        _panel(axes[0, 0], gt["gt_rgb"], "ground truth color")
        _panel(axes[0, 1], gt["gt_depth"], "ground truth depth", vmax=vmax)
        axes[0, 2].axis("off")
        for i, (m, v) in enumerate(rows, start=1):
            text = {k: METRICS[k].describe(float(v[k])) for k in ("psnr", "depth_l1_cm", "normal_err_deg")}
            _panel(axes[i, 0], np.clip(v["rgb"], 0, 1), f"{m}: {text['psnr']}")
            _panel(axes[i, 1], v["depth"], text["depth_l1_cm"], vmax=vmax)
            _panel(axes[i, 2], 0.5 * (1 - v["normal"]), text["normal_err_deg"])
    fig.suptitle(f"Novel view (scene {scene}, evaluation view 0)", fontsize=9)
    return _save(fig, path, plt)


def _panel(ax, img, title, vmax=None):
    ax.imshow(img, cmap="viridis" if img.ndim == 2 else None, vmin=0 if vmax else None, vmax=vmax)
    ax.set_title(title, fontsize=8)
    ax.axis("off")


def _save(fig, path: Path, plt) -> Path:
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path
