"""The code runs on Python 3.10, the oldest pyproject.toml admits: a static check of every module
(syntax 3.10 can parse, and no standard-library module newer than 3.10 imported without a guard),
and plain `pytest` (not only `python -m pytest`) collects the suite."""

import ast
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OLDEST = (3, 10)
NEWER_STDLIB = {"tomllib": (3, 11), "wsgiref.types": (3, 11)}  # modules added after 3.10


def _sources() -> list[Path]:
    return sorted(p for d in ("flightrecon", "tools", "tests", "examples") for p in (ROOT / d).rglob("*.py"))


def _guarded(node: ast.AST, parents: dict) -> bool:
    """Inside `if sys.version_info >= (3, k):`."""
    while node in parents:
        node = parents[node]
        if isinstance(node, ast.If) and "version_info" in ast.unparse(node.test):
            return True
    return False


def test_pyproject_names_the_oldest_python_checked_here():
    text = (ROOT / "pyproject.toml").read_text()
    assert re.search(r'requires-python = ">=3\.10"', text)
    assert "tomli" in text  # tomllib's package for 3.10


def test_every_module_parses_as_python_3_10_and_guards_newer_imports():
    problems = []
    for path in _sources():
        source = path.read_text()
        try:
            tree = ast.parse(source, filename=str(path), feature_version=OLDEST)
        except SyntaxError as exc:
            problems.append(f"{path.relative_to(ROOT)}:{exc.lineno}: not Python {OLDEST}: {exc.msg}")
            continue
        parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                if name in NEWER_STDLIB and not _guarded(node, parents):
                    problems.append(f"{path.relative_to(ROOT)}:{node.lineno}: imports {name} (Python "
                                    f"{NEWER_STDLIB[name]}) without a version guard")
    assert not problems, "\n".join(problems)


def test_the_check_itself_finds_what_it_looks_for():
    try:
        ast.parse("match = 1\nx = [y for y in (1,) if (z := y)]\nmatch x:\n    case 1: pass\n", feature_version=(3, 9))
        raise AssertionError("a match statement (3.10) parsed as 3.9")
    except SyntaxError:
        pass
    tree = ast.parse("import sys\nif sys.version_info >= (3, 11):\n    import tomllib\nimport tomllib\n")
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
    imports = sorted((n for n in ast.walk(tree) if isinstance(n, ast.Import) and n.names[0].name == "tomllib"),
                     key=lambda n: n.lineno)
    assert [_guarded(n, parents) for n in imports] == [True, False]


def test_plain_pytest_collects_the_suite():
    """The `pytest` script, unlike `python -m pytest`, does not put the working folder on sys.path."""
    script = Path(sys.executable).parent / "pytest"
    r = subprocess.run([str(script), "--collect-only", "-q", "-p", "no:cacheprovider"], cwd=ROOT,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert re.search(r"\d+ tests? collected", r.stdout)
