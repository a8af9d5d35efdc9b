"""The package's house by role: the root holds at most four modules, and the core (cmcl/ without the command line
and run management of cmcl/run/ and the entry point cmcl/__main__.py) imports neither of them, nor Ray, nor the
service, read from every import statement of the tracked files (lazy imports inside functions too)."""

import ast
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def tracked(prefix: str) -> list[Path]:
    out = subprocess.run(["git", "ls-files", f"{prefix}*.py"], cwd=ROOT, capture_output=True, text=True, check=True)
    return [ROOT / line for line in out.stdout.split()]


def imported(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    return names


def test_the_package_root_holds_at_most_four_modules():
    root = sorted(p.name for p in tracked("cmcl/") if p.parent == ROOT / "cmcl")
    assert len(root) <= 4, root


def test_the_core_imports_neither_the_command_line_nor_run_folders_nor_the_service():
    core = [p for p in tracked("cmcl/") if not p.is_relative_to(ROOT / "cmcl" / "run")
            and p != ROOT / "cmcl" / "__main__.py"]
    assert len(core) > 50
    offending = {str(p.relative_to(ROOT)): sorted(n for n in imported(p)
                                                  if n.startswith(("cmcl.run.", "cmcl.__main__", "services", "ray"))
                                                  or n == "cmcl.run")
                 for p in core}
    assert {k: v for k, v in offending.items() if v} == {}
