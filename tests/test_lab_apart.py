"""The research record (lab/) stands beside the product: no tracked file of cmcl/, services/, experiments/ or tests/
imports it (every import statement, lazy imports inside functions too), and the packages pyproject's setuptools find
builds into the wheel do not include it."""

import ast
import subprocess
import tomllib
from pathlib import Path

from setuptools import find_packages

ROOT = Path(__file__).resolve().parent.parent
PRODUCT = ("cmcl", "services", "experiments", "tests")


def imported(path: Path) -> set[str]:
    """The top-level names of every absolute import in `path`."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_no_file_of_the_product_or_its_tests_imports_the_record():
    out = subprocess.run(["git", "ls-files", *(f"{p}/*.py" for p in PRODUCT)], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout.split()
    files = [ROOT / name for name in out]
    assert len(files) > 100
    assert sorted(str(f.relative_to(ROOT)) for f in files if "lab" in imported(f)) == []


def test_the_parser_sees_a_lazy_import_of_the_record(tmp_path):
    source = tmp_path / "module.py"
    source.write_text("def f():\n    from lab.report.stats import fmt\n    import lab\n")
    assert "lab" in imported(source)


def test_the_wheels_packages_leave_the_record_out():
    find = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    packages = find_packages(str(ROOT), include=find["include"], exclude=find.get("exclude", ()))
    assert "experiments" in packages and "cmcl" in packages
    assert [p for p in packages if p == "lab" or p.startswith("lab.")] == []
