"""The plan's endpoints (plan.md) from the re-flown runs and the committed confirmatory runs of the
same units: `python results/safety/write_comparison.py` from the repository root writes
comparison.md beside this file, and the sweep's tables and figures over all the plan's runs into
runs/sweep_cpu/report (the plan's two sweeps each write a report of their own runs only).

Primary: per method, flights inside the margin and flights with a contact, before (the committed
runs of these 12 units) and now. Secondary: PSNR at frame 90, new - committed on the same unit, mean
and 95% t-interval over the units; and whether the new mean lies inside the committed runs' own 95%
interval over the same units."""

from pathlib import Path

from flightrecon.evaluation.intervals import mean_interval, paired_difference
from flightrecon.experiments.report import collect, safety_cells, write_figures, write_tables

HERE = Path(__file__).resolve().parent
NEW = HERE / "runs" / "sweep_cpu"
OLD = HERE.parent / "confirm" / "runs" / "sweep_cpu"
UNITS = [f"{s}.v5" for s in ("office0", "office1", "office2", "office3", "office4", "room0", "room1", "room2")] + \
        [f"{s}.v4" for s in ("office0", "office1", "office2", "office3")]
METHODS = ["gaussmi2d_frontier", "gaussmi2d", "activegs", "activegs_native", "fisherrf", "gaussmi", "random"]


def _records(root: Path) -> list[dict]:
    return collect([root / u / m / "seed0" for u in UNITS for m in METHODS])


def _by_unit(recs: list[dict]) -> dict[tuple[str, str], dict]:
    return {(r["scene"], r["method"]): r for r in recs}


def _safety_cells(recs: list[dict]) -> list[str]:
    """Flights inside the margin, flights with contacts, lowest clearance (the report's counts)."""
    below, _, lowest, contacts = safety_cells(recs)
    return [below, contacts, lowest]


def main() -> None:
    flown = _records(NEW)
    report = NEW / "report"
    write_tables(flown, report)
    write_figures(flown, report)
    new, old = _by_unit(flown), _by_unit(_records(OLD))
    lines = [f"# The plan's endpoints ({len(new)} of {len(UNITS) * len(METHODS)} re-flown runs)", "",
             "Before: the committed confirmatory runs (results/confirm/runs) of the same 12 units; now: "
             "runs/sweep_cpu here. 'Inside margin': flights with a frame below planner.safety_margin after "
             "take-off; 'lowest': the lowest clearance [m] of any of the method's flights.", "",
             "| Method | Runs | Inside margin before | Contacts before | Lowest before | Inside margin now | "
             "Contacts now | Lowest now | PSNR now − before [dB] | Committed PSNR (95% int.) | Now PSNR | "
             "Now inside committed interval |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for m in METHODS:
        units = [u for u in UNITS if (u, m) in new and (u, m) in old]
        before = [old[(u, m)] for u in units]
        now = [new[(u, m)] for u in units]
        diff = paired_difference({u: new[(u, m)]["psnr"] for u in units}, {u: old[(u, m)]["psnr"] for u in units})
        committed = mean_interval(r["psnr"] for r in before)
        now_mean = mean_interval(r["psnr"] for r in now)
        inside = abs(now_mean.mean - committed.mean) <= committed.half_width
        lines.append(f"| {m} | {len(units)} | " + " | ".join(_safety_cells(before)) + " | "
                     + " | ".join(_safety_cells(now)) + f" | {diff.format(2)}{'*' if diff.excludes_zero() else ''}"
                     f" | {committed.format(2)} | {now_mean.mean:.2f} | {'yes' if inside else 'no'} |")
    every = [u for u in UNITS for m in METHODS if (u, m) in new and (u, m) in old]
    lines += ["", f"All methods: {sum(not new[k]['margin'].kept for k in new)} of {len(new)} flights inside the "
              f"margin now, {sum(new[k]['contacts'] > 0 for k in new)} with contacts; "
              f"{len(every)} paired runs. * : the interval excludes zero.", ""]
    (HERE / "comparison.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
