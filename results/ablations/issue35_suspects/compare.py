"""Write report/ comparing the arms of this ablation as if they were methods (run from main's checkout:
`python results/ablations/issue35_suspects/compare.py`).

Every arm flies `gaussmi2d` under its own run root, so the sweep's reports each hold one method; here
the runs of each root are named after their arm and handed to the report's own tables, so
report/paired_gaussmi2d.md holds each arm minus the reference, seeds averaged per scene, 95% t over
the scenes."""

from pathlib import Path

from flightrecon.experiments.report import collect, write_figures, write_tables

HERE = Path(__file__).resolve().parent
ARMS = {"reference": "gaussmi2d", "edge_mask": "gaussmi2d+edge_mask",
        "scoring_160x120": "gaussmi2d+scoring_160x120"}

recs = []
for root, label in ARMS.items():
    runs = sorted((HERE / root / "sweep_cpu").glob("*/gaussmi2d/seed*"))
    arm = collect(runs)
    for r in arm:
        r["method"] = label
    recs += arm
report = HERE / "report"
files = write_tables(recs, report) + write_figures(recs, report)
print((report / "overall.md").read_text())
print((report / "paired_gaussmi2d.md").read_text())
print(f"{len(recs)} runs; {len(files)} files in {report}")
