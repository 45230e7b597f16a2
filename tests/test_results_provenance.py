"""The code and CPU a results README says its runs were flown with are what the runs' provenance.json say.

Every run stamps each of its segments with the commit (and whether the tree was clean) and the CPU
(`flightrecon.provenance`). A README under results/ whose folder holds runs states them in one
table, `| runs | flights | commit | CPU |`, one row per group of run folders (a glob relative to the
README), and this test holds every row to the files: the number of runs, the set of commits and the
set of CPUs. Every run below the README must be in some row, so no flight is left out of a claim.
Outside that table such a README names no CPU, nor does the project README's Results section: a
CPU stated in prose is a claim nobody checks.
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
HEADER = ["runs", "flights", "commit", "CPU"]
CPU_WORDS = re.compile(r"Xeon|EPYC|Ryzen|Core i[3579]|AVX", re.IGNORECASE)


def cpu_text(cpu: dict) -> str:
    """A provenance CPU as the tables write it: model, cores and the widest vector extension."""
    isa = "AVX-512" if "avx512f" in cpu["isa"] else "AVX2" if "avx2" in cpu["isa"] else "no AVX2"
    return f"{cpu['model']}, {cpu['cores']} cores, {isa}"


def commit_text(segment: dict) -> str:
    return f"{segment['commit'][:7]} {'dirty' if segment['dirty'] else 'clean'}"


def provenance_tables(text: str) -> list[list[list[str]]]:
    """The rows (cells, backticks dropped) of every table in `text` whose header is HEADER."""
    tables, rows, inside = [], None, False
    for line in text.splitlines() + [""]:
        cells = [c.strip().strip("`") for c in line.strip().strip("|").split("|")] if line.startswith("|") else None
        if cells == HEADER:
            rows, inside = [], True
        elif inside and cells is not None:
            if not set("".join(cells)) <= set("-: "):
                rows.append(cells)
        elif inside:
            tables.append(rows)
            inside = False
    return tables


def prose(text: str) -> str:
    """`text` without its provenance tables."""
    out, inside = [], False
    for line in text.splitlines():
        cells = [c.strip().strip("`") for c in line.strip().strip("|").split("|")] if line.startswith("|") else None
        inside = (cells == HEADER) or (inside and cells is not None)
        if not inside:
            out.append(line)
    return "\n".join(out)


def check_readme(readme: Path, runs: list[Path], counted: set[Path] | None = None) -> list[str]:
    """What the README's provenance table gets wrong about `runs` (run folders below it), or [].
    A row counts the run folders its glob matches, only those in `counted` when given (the committed
    ones: a sweep still writing into a results folder leaves unfinished runs beside them)."""
    tables = provenance_tables(readme.read_text(encoding="utf-8"))
    if len(tables) != 1:
        return [f"{readme}: expected one `| runs | flights | commit | CPU |` table, found {len(tables)}"]
    errors, claimed = [], set()
    for runs_glob, flights, commits, cpus in tables[0]:
        matched = sorted(p.parent for p in readme.parent.glob(f"{runs_glob}/provenance.json")
                         if counted is None or p.parent in counted)
        claimed.update(matched)
        segments = [s for d in matched for s in json.loads((d / "provenance.json").read_text())["segments"]]
        found = (str(len(matched)), "; ".join(sorted({commit_text(s) for s in segments})),
                 "; ".join(sorted({cpu_text(s["cpu"]) for s in segments})))
        stated = (flights, "; ".join(sorted(commits.split("; "))), "; ".join(sorted(cpus.split("; "))))
        if found != stated:
            errors.append(f"{readme}, row {runs_glob}: states {stated}, provenance.json says {found}")
    errors += [f"{readme}: run {d} is in no row" for d in sorted(set(runs) - claimed)]
    if CPU_WORDS.search(prose(readme.read_text(encoding="utf-8"))):
        errors.append(f"{readme}: names a CPU outside its provenance table")
    return errors


def _committed(name: str) -> list[Path]:
    """The committed files under results/ with this file name."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "results"], cwd=REPO, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the committed files are not known")
    return [REPO / f for f in out.decode().split("\0") if f and Path(f).name == name]


def test_every_results_readme_states_its_runs_code_and_cpus_as_their_provenance_does():
    runs = [p.parent for p in _committed("provenance.json")]
    readmes = _committed("README.md")
    checked, errors = 0, []
    def nearest(run: Path) -> Path:  # the README closest above a run answers for it
        return max((r for r in readmes if r.parent in run.parents), key=lambda r: len(r.parts))

    for readme in readmes:
        mine = [d for d in runs if readme.parent in d.parents and nearest(d) == readme]
        if mine:
            checked += 1
            errors += check_readme(readme, mine, set(runs))
    assert checked >= 2 and errors == []  # the confirmatory and paper-setting READMEs among them


def test_the_project_readme_names_no_cpu_in_its_results():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    results = text.split("\n## Results", 1)[1].split("\n## ", 1)[0]
    assert "provenance" in results and not CPU_WORDS.search(results)


def _run(folder: Path, commit: str, model: str, isa: list[str]) -> None:
    folder.mkdir(parents=True)
    segment = {"commit": commit, "dirty": False, "cpu": {"model": model, "cores": 2, "isa": isa}}
    (folder / "provenance.json").write_text(json.dumps({"segments": [segment]}))


def test_a_wrong_cpu_a_missing_run_or_a_cpu_in_prose_is_found(tmp_path):
    xeon, epyc = "Intel(R) Xeon(R) Processor", "AMD EPYC"
    _run(tmp_path / "runs/a/m1/seed0", "0553db2aaaa", xeon, ["avx2", "avx512f"])
    _run(tmp_path / "runs/a/m2/seed0", "0553db2aaaa", epyc, ["avx2", "avx512f"])
    _run(tmp_path / "runs/b/m1/seed0", "0553db2aaaa", epyc, ["avx2"])
    runs = sorted(p.parent for p in tmp_path.glob("runs/*/*/seed0/provenance.json"))
    readme = tmp_path / "README.md"
    table = ("| runs | flights | commit | CPU |\n|---|---|---|---|\n"
             "| `runs/a/*/seed0` | 2 | 0553db2 clean | AMD EPYC, 2 cores, AVX-512; {xeon}, 2 cores, AVX-512 |\n"
             "| `runs/b/*/seed0` | 1 | 0553db2 clean | AMD EPYC, 2 cores, AVX2 |\n").replace("{xeon}", xeon)
    readme.write_text("# Runs\n\n" + table + "\nEvery flight is in the table.\n")
    assert check_readme(readme, runs) == []
    assert "provenance.json says" in check_readme(readme, runs, set(runs[1:]))[0]  # an uncounted run is no flight
    readme.write_text(table.replace(f"; {xeon}, 2 cores, AVX-512", ""))  # the Xeon flight left out of the claim
    assert "provenance.json says" in check_readme(readme, runs)[0]
    readme.write_text(table.split("| `runs/b")[0])  # a run in no row
    assert check_readme(readme, runs) == [f"{readme}: run {runs[2]} is in no row"]
    readme.write_text(table + "\nAll flown on a 2-core AMD EPYC.\n")
    assert check_readme(readme, runs) == [f"{readme}: names a CPU outside its provenance table"]
