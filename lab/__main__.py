"""Command line of the research record: the report's tables, the figures and the stall records, from the summaries
the grid runner (`python -m experiments run GRID`) wrote under lab/results/.

    python -m lab report [--update lab/RESULTS.md | README.md | docs/LEARNING.md] [--results lab/results]
    python -m lab figures [--results lab/results]
    python -m lab stalls FOLDER [FOLDER ...]      (e.g. lab/results/curriculum: its runs/ directories)

Run from the repository's root (the record is not an installed package). Exit code 2 when a page or a folder named
does not exist, before any table is drawn.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from experiments.__main__ import shown
from lab.report.report import blocks, figures, update
from lab.report.stalls import analyse_folder


def report(args: argparse.Namespace) -> int:
    if args.update and not Path(args.update).is_file():  # before the tables are drawn (a minute of statistics)
        print(f"error: --update {args.update}: no such markdown file (the page whose marked blocks get the tables)",
              file=sys.stderr)
        return 2
    new = blocks(args.results)
    for name, body in new.items():
        print(f"{name}:\n{body}\n")
    for png in figures(args.results):
        print(f"figure: {shown(png)}")
    if args.update:
        update(Path(args.update), new)
    return 0


def stalls(args: argparse.Namespace) -> int:
    missing = [folder for folder in args.folders if not (folder / "runs").is_dir()]
    if missing:  # a folder without runs/ (a typo) would write nothing and say nothing
        print(f"error: {missing[0]} holds no runs/ folder (a grid folder, e.g. lab/results/curriculum)",
              file=sys.stderr)
        return 2
    for folder in args.folders:
        for path in analyse_folder(folder):
            print(f"stall record: {shown(path)}")
    return 0


def draw(args: argparse.Namespace) -> int:
    for png in figures(args.results):
        print(f"figure: {shown(png)}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The command line: report, figures, stalls."""
    parser = argparse.ArgumentParser(prog="python -m lab", description=__doc__.split("\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    for name, text in (("report", "print the tables, draw the figures, optionally update a page"),
                       ("figures", "draw the figures only")):
        p = commands.add_parser(name, help=text)
        p.add_argument("--results", type=Path, default=None, help="results root (default lab/results)")
        if name == "report":
            p.add_argument("--update", help="a markdown file whose marked blocks get the new tables")
    p = commands.add_parser("stalls", help="write the stall records of a curriculum grid's finished runs")
    p.add_argument("folders", nargs="+", type=Path, metavar="FOLDER", help="a grid folder with runs/ and summaries/")
    return parser


COMMANDS = {"report": report, "figures": draw, "stalls": stalls}


def main(argv: list[str] | None = None) -> int:
    """Run the command `argv` names (default: the command line's); its exit code."""
    args = build_parser().parse_args(argv)
    return COMMANDS[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
