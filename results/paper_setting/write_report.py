"""Rewrite runs/office0/report from every finished paper-setting flight, with the code they were
flown with (run from the 0553db2 worktree: `cd <worktree> && python <this file>`).

Needed when flights were split between sweeps with different --methods (0553db2 has no per-run lock,
so two sweeps over one root must not share a method): each such sweep writes a report of its own
methods only. The sweep of the plan's full command writes the same report once all 12 are in.
It also writes the plan's own comparison, which the sweep's tables lack: each method's paired
difference to activegs with its 95% t-interval, the scene as the unit (paired_to_activegs.md)."""

from pathlib import Path

from flightrecon.experiments.report import ALL_UNITS, collect, paired_interval, write_figures, write_tables
from flightrecon.experiments.sweep import failure, plan_runs

ROOT = Path(__file__).resolve().parent / "runs"
specs = plan_runs("paper/office0", ["office0", "office1", "room0", "room1"],
                  ["gaussmi2d", "gaussmi2d_frontier", "activegs"], 1,
                  ["planner.library=moving", "evaluation.every=50", "output.diagnose=true"], str(ROOT))
report = specs[0].run_dir.parents[2] / "report"
failed = {str(s.run_dir): why for s in specs if (why := failure(s)) is not None}
recs = collect([s.run_dir for s in specs])
files = write_tables(recs, report, failed) + write_figures(recs, report)
print((report / "overall.md").read_text())

MEASURES = [("psnr", "PSNR [dB]", 2), ("psnr_covered", "PSNR cov. [dB]", 2), ("depth_l1_cm", "depth L1 [cm]", 2),
            ("fscore", "F-score", 3)]
lines = ["**Paired difference to activegs (method - activegs on the same scene, one seed each; mean over "
         "scenes ± 95% t-interval, the scene as the unit; * excludes zero)**", "",
         "| Method | Scenes | " + " | ".join(h for _, h, _ in MEASURES) + " |", "|---|---|" + "---|" * len(MEASURES)]
for m in ("gaussmi2d", "gaussmi2d_frontier"):
    ivs = [(paired_interval(recs, m, "activegs", key, ALL_UNITS), digits) for key, _, digits in MEASURES]
    lines.append(f"| {m} | {ivs[0][0].n} | " + " | ".join(iv.format(d) + ("*" if iv.excludes_zero() else "")
                                                          for iv, d in ivs) + " |")
(report / "paired_to_activegs.md").write_text("\n".join(lines) + "\n")
files.append(report / "paired_to_activegs.md")
print((report / "paired_to_activegs.md").read_text())
print(f"{len(recs)} finished flights; {len(files)} files in {report}")
