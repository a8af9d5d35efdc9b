"""Headless Chromium's view of the console dashboard (deploy/prometheus/consoles/cmcl.html), shared by the live
tests (tests/test_live_dashboard.py: embedded run; tests/test_compose_live.py: the compose stack)."""

from __future__ import annotations

import re

from services.observability.report_schema import ROLES

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--window-size=1500,1900",
                  "--virtual-time-budget=20000"]
SUFFIX = {"": 1.0, "k": 1e3, "M": 1e6, "G": 1e9, "m": 1e-3}


def number(text: str) -> float:
    """A value as the console template prints it: '95.36', '1.43k', '2M /s', '200m'."""
    match = re.match(r"\s*([-0-9.e+]+)\s*([kMGm]?)", text)
    assert match, text
    return float(match.group(1)) * SUFFIX[match.group(2)]


def check_console_dom(dom: str) -> dict[str, str]:
    """Every graph panel but g-win (no data in navigation) plots a series, the 'Restarts by role' table has a row
    for each role, and the 12 'now' cells have values, the rates above 0 (a run in progress)."""
    panels = re.findall(r'<div id="(g-[a-z-]+)" class="cmcl-graph"(.*?)</div></div>', dom, re.S)
    assert len(panels) >= 17, f"{len(panels)} graph panels in the DOM"
    empty = sorted(name for name, body in panels if "<svg" not in body or "<path" not in body)
    assert empty == ["g-win"], f"panels without a plotted series: {empty} (g-win has no data in navigation)"
    restarts = re.findall(r"<td>([a-z]+)</td><td>([0-9.]+)</td>", dom)  # the "Restarts by role" rows
    assert sorted(role for role, _ in restarts) == sorted(ROLES), restarts  # each role, from the start
    now = dict(re.findall(r'<td id="(now-[a-z-]+)"><a[^>]*>([^<]*)</a>', dom))
    assert len(now) == 12 and all(v.strip() not in ("", "-") for v in now.values()), now
    assert number(now["now-env-rate"]) > 0 and number(now["now-update-rate"]) > 0, now
    return now
