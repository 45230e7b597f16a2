#!/usr/bin/env python3
"""List the longest functions of the package and the C++ extension (lines from def to last line).

A review aid for keeping functions short: `python tools/longest_functions.py [--top N]`.
C++ functions are found by a brace count from a line that opens a top-level definition, which is
enough for csrc/'s plain style (no macros that open braces)."""

from __future__ import annotations

import argparse
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CPP_DEF = re.compile(r"^(?:static\s+|inline\s+|template\s*<[^>]*>\s*)*[\w:<>,\s\*&]+?\b(\w+)\s*\([^;]*$")


def python_functions(root: Path):
    for path in sorted((root / "flightrecon").rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield node.end_lineno - node.lineno + 1, f"{path.relative_to(root)}:{node.lineno} {node.name}"


def cpp_functions(root: Path):
    for path in sorted(list((root / "csrc").glob("*.cpp")) + list((root / "csrc").glob("*.h"))):
        lines = path.read_text().splitlines()
        i = 0
        while i < len(lines):
            m = CPP_DEF.match(lines[i])
            if m and not lines[i].startswith((" ", "\t", "}", "#", "//")) and m.group(1) not in ("if", "for", "while"):
                depth, j, opened = 0, i, False
                while j < len(lines):
                    depth += lines[j].count("{") - lines[j].count("}")
                    opened |= "{" in lines[j]
                    if opened and depth <= 0:
                        break
                    if not opened and lines[j].rstrip().endswith(";"):
                        break
                    j += 1
                if opened:
                    yield j - i + 1, f"{path.relative_to(root)}:{i + 1} {m.group(1)}"
                    i = j
            i += 1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--top", type=int, default=15)
    args = ap.parse_args()
    for title, found in (("python", python_functions(ROOT)), ("c++", cpp_functions(ROOT))):
        print(f"# {title}")
        for n, where in sorted(found, reverse=True)[:args.top]:
            print(f"{n:5d}  {where}")


if __name__ == "__main__":
    main()
