"""The screen's table (protocol in lab/RESULTS.md, "Sampling rules that help: the screen"): one row per arm with
its learning measures, the manipulation check and the code it ran, then the selection rule applied
(experiments.screen_selection), as the page says it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.replay.registry import spec_of
from experiments.labels import ARM_LABEL
from experiments.provenance import cell_versions
from experiments.screen_arms import SCREEN_ARMS, SCREEN_REFERENCES, SCREEN_SEEDS, rule_algorithm
from experiments.screen_selection import acted, arm_runs, at_seeds, manipulation_ratio, round_two_arms, selection
from lab.report.stats import fmt


def arm_table(runs: list[dict[str, Any]], roles: dict[str, str]) -> str:
    """Per arm of `roles` (arm -> its role in the grid, in table order): role, seeds, code, area under the training
    coverage curve, held-out coverage and success, episodes to MA 0.9, ESS in the first quarter, the manipulation
    ratio and its verdict."""
    lines = ["| arm | role | seeds | code | area under coverage | held-out coverage | held-out success | "
             "episodes to MA 0.9 | ESS, first quarter | reward rows sampled / buffer, first quarter | "
             "manipulation check |", "| --- " * 11 + "|"]
    for arm, role in roles.items():
        rs = arm_runs(runs, arm)
        if not rs:
            continue
        ratios = [x for x in map(manipulation_ratio, rs) if x is not None]
        check = "—" if arm == "maddpg" else "no data" if acted(rs) is None else \
            "acted" if acted(rs) else "did not act"
        ess = [r["ess_first_quarter"] for r in rs if r.get("ess_first_quarter") is not None]
        lines.append(f"| {ARM_LABEL[arm]} | {role} | {len(rs)} | {cell_versions(rs)[0]} | " + " | ".join(
                         fmt([r[k] for r in rs], d, k) for k, d in (("auc_coverage", 3), ("held_out_coverage", 3),
                                                                    ("held_out_success", 3), ("episodes_to_90", 0)))
                     + f" | {np.mean(ess):.2f} | " + (f"{np.mean(ratios):.2f}" if ratios else "—") + f" | {check} |")
    return "\n".join(lines)


def screen_table(runs: list[dict[str, Any]]) -> str:
    """The screen per arm (arm_table) at SCREEN_SEEDS: the candidates (those round two dropped named so once round one
    is in) and the references run beside them; then the runs at other seeds, listed and not read; and a note on the
    ESS of the arms whose learner picks among candidates, once one has a run."""
    second = round_two_arms(runs)
    roles = {arm: "reference" if arm in SCREEN_REFERENCES else
             "candidate" if second is None or arm in second else "candidate, round one only" for arm in SCREEN_ARMS}
    table = arm_table(at_seeds(runs, SCREEN_SEEDS), roles)
    outside = sorted((r for r in runs if r.get("arm") in SCREEN_ARMS and r["seed"] not in SCREEN_SEEDS),
                     key=lambda r: (list(SCREEN_ARMS).index(r["arm"]), r["seed"]))
    if outside:
        table += ("\n\nRun before the amendment at seeds outside the screen's, not in the table or the selection: "
                  + "; ".join(f"{ARM_LABEL[r['arm']]} seed {r['seed']} (area {r['auc_coverage']:.3f})"
                              for r in outside) + ".")
    pickers = [ARM_LABEL[arm] for arm, sets in SCREEN_ARMS.items()
               if spec_of(rule_algorithm(sets)).pick is not None and arm_runs(runs, arm)]
    if not pickers:
        return table
    return table + (f"\n\nESS is that of the buffer's draw; for {', '.join(pickers)} that is the uniform candidate "
                    "batch (1.00 by construction), and the learner's pick among the candidates shows in the reward "
                    "rows' ratio, which the inline runner measures on the picked rows.")


def screen_selection(runs: list[dict[str, Any]]) -> str:
    """The selection rule applied (`selection`), as the page says it."""
    chosen = selection(runs)
    if not chosen.chosen:
        return chosen.reason()
    return (f"Selected for the confirmation (code {chosen.code}): " + ", ".join(ARM_LABEL[a] for a in chosen.chosen)
            + f". Ranked by mean area over seeds {', '.join(map(str, SCREEN_SEEDS))} among round two's candidates "
              f"that acted (MADDPG {chosen.reference:.3f}): "
            + "; ".join(f"{ARM_LABEL[a]} {area:.3f}" for area, _, a in chosen.ranked) + ".")
