"""Exactly-once inserts: which (writer, incarnation, seq) chunks the replay has stored, whatever order they came in.

Where it sits: `services.roles.replay_server.ReplayServer.insert` asks `InsertLedger.accept` before storing a chunk. A
writer's chunks are numbered 0, 1, 2, ... per incarnation; a retried or reordered chunk is stored if and only if
its number was never stored before, so a chunk that arrives behind a later one is not lost, and a duplicate is
never stored twice. Per writer the ledger keeps a watermark (every seq <= it is stored) and the stored seqs above
it; the set is compacted as gaps fill and bounded by `max_pending` (beyond it the oldest gap is given up and
counted). Pure Python.
"""

from __future__ import annotations

from typing import Any

MAX_PENDING = 4096  # stored seqs above a writer's watermark before the oldest gap is given up


class InsertLedger:
    """Stored chunk numbers per writer key ("writer:incarnation")."""

    def __init__(self, max_pending: int = MAX_PENDING):
        self.max_pending = int(max_pending)
        self.watermark: dict[str, int] = {}  # key -> largest w with every seq <= w stored (−1: none)
        self.pending: dict[str, set[int]] = {}  # key -> stored seqs above the watermark
        self.gaps_given_up = 0

    def seen(self, key: str, seq: int) -> bool:
        """Whether chunk `seq` of writer `key` was stored already."""
        return seq <= self.watermark.get(key, -1) or seq in self.pending.get(key, ())

    def accept(self, key: str, seq: int) -> bool:
        """Record chunk `seq` of `key` as stored; False (and nothing recorded) if it was stored before."""
        seq = int(seq)
        if seq < 0:
            raise ValueError(f"chunk seq must be >= 0, got {seq}")
        if self.seen(key, seq):
            return False
        mark, pending = self.watermark.get(key, -1), self.pending.setdefault(key, set())
        pending.add(seq)
        while mark + 1 in pending:  # compact: the gap below is filled
            mark += 1
            pending.discard(mark)
        while len(pending) > self.max_pending:  # a gap that never fills: give it up, keep memory bounded
            self.gaps_given_up += min(pending) - mark - 1
            mark = min(pending)
            pending.discard(mark)
            while mark + 1 in pending:
                mark += 1
                pending.discard(mark)
        self.watermark[key] = mark
        return True

    def state_dict(self) -> dict[str, Any]:
        """Codec-ready: {"watermark": {key: int}, "pending": {key: [int]}, "gaps_given_up": int}."""
        return {"watermark": dict(self.watermark), "pending": {k: sorted(v) for k, v in self.pending.items() if v},
                "gaps_given_up": self.gaps_given_up}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore `state_dict()` output (validated before anything changes)."""
        watermark = {str(k): int(v) for k, v in state["watermark"].items()}
        pending = {str(k): {int(s) for s in v} for k, v in state["pending"].items()}
        for key, seqs in pending.items():
            if any(s <= watermark.get(key, -1) for s in seqs):
                raise ValueError(f"insert ledger of {key!r}: pending seqs must lie above its watermark")
        self.watermark, self.pending = watermark, pending
        self.gaps_given_up = int(state.get("gaps_given_up", 0))
