"""Learner throughput: one full CMCL update with stacked modules vs a per-agent / per-teacher loop peer.

One "update" = MADDPG step for N agents on per-agent minibatches (S = 128) + one fit step of K teachers per agent
(teacher batches from their own folds, targets from the learner's target nets) + one ICM step per agent.
Also times a full rescoring of a 5000-row buffer (TD targets, teacher errors, cross-validated difficulty, ICM
curiosity). Rounds of ours and the peer are interleaved (the machine is shared); the median update round and the
best rescoring run are reported.

Then one update as the runners do it at the default settings (both run the service's roles: `FilledRoles`, the roles
called in this process as `--runner inline` calls them), CMCL against MADDPG on the same filled buffer.

Run: .venv/bin/python bench/learner_throughput.py   (``ratio: X`` = ours / peer updates per second; last line
``cmcl/maddpg cost: X`` = seconds of one CMCL update over one MADDPG update, target <= 3)
"""

from __future__ import annotations

import copy
import statistics
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from cmcl.config import load_config
from cmcl.learners.maddpg import MADDPG
from cmcl.learners.network_steps import curiosity_values, fit_teachers, teacher_errors
from cmcl.replay.buffer_steps import fold_draw_indices
from cmcl.replay.messages import CURIOSITY, DIFFICULTY, Scorer
from cmcl.scorers.difficulty import cross_validated_difficulty
from cmcl.scorers.icm import ICM
from cmcl.scorers.teachers import TeacherEnsemble

ROOT = Path(__file__).resolve().parents[1]
N, OD, AD, S, K, M = 4, 18, 2, 128, 5, 5000
GAMMA, TAU, CLIP = 0.99, 0.01, 0.5
ROUNDS, UPDATES_PER_ROUND = 7, 12


def make_buffer(seed: int = 0) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Random joint rows (obs [M,N,OD], act [M,N,AD], rew [M,N], next_obs, done [M]) and folds by 30-step episode."""
    rng = np.random.default_rng(seed)
    rows = {
        "obs": rng.normal(size=(M, N, OD)).astype(np.float32),
        "act": rng.uniform(-1, 1, size=(M, N, AD)).astype(np.float32),
        "rew": rng.normal(size=(M, N)).astype(np.float32),
        "next_obs": rng.normal(size=(M, N, OD)).astype(np.float32),
        "done": np.zeros(M, np.float32),
    }
    return rows, (np.arange(M) // 30) % K


# ----------------------------------------------------------------------------- ours (stacked)
class Ours:
    """The cmcl classes: every agent / teacher stacked into one module."""

    def __init__(self) -> None:
        self.m = MADDPG(N, OD, AD, seed=0)
        self.t = TeacherEnsemble(N, in_dim=N * (OD + AD), num_folds=K, seed=1)
        self.icm = ICM(N, OD, AD, seed=2)
        self.agents = np.arange(N)

    def update(self, rows: dict, fold: np.ndarray, rng: np.random.Generator) -> None:
        idx = rng.integers(0, M, size=(N, S))
        self.m.update({k: v[idx] for k, v in rows.items()})
        tidx = fold_draw_indices(fold, range(K), S, rng, draws=N)  # [1, N, K, S]
        fit_teachers(self.t, {k: v[tidx] for k, v in rows.items()}, self.agents, self.m)
        i = rng.integers(0, M, size=S)
        per_agent = [torch.from_numpy(rows[k][i]).transpose(0, 1) for k in ("obs", "act", "next_obs")]
        self.icm.train_step(*per_agent)

    def rescore(self, rows: dict, fold: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c, _ = cross_validated_difficulty(teacher_errors(self.t, rows, self.agents, self.m), fold)
        return c.T, curiosity_values(self.icm, rows, self.agents).T


# ----------------------------------------------------------------------------- peer (loops)
def mlp(i: int, o: int, hidden=(64, 64), out_act: type[nn.Module] | None = None) -> nn.Sequential:
    """Plain nn.Sequential MLP."""
    layers: list[nn.Module] = []
    for a, b in zip([i, *hidden[:-1]], hidden, strict=True):
        layers += [nn.Linear(a, b), nn.ReLU()]
    layers.append(nn.Linear(hidden[-1], o))
    if out_act is not None:
        layers.append(out_act())
    return nn.Sequential(*layers)


class Peer:
    """Straightforward implementation: one nn.Sequential + Adam per agent / teacher / ICM part, Python loops."""

    def __init__(self) -> None:
        with torch.random.fork_rng():  # nn.Linear init draws from the global generator: keep it untouched
            torch.manual_seed(0)
            self._build()

    def _build(self) -> None:
        cin = N * (OD + AD)
        self.actors = [mlp(OD, AD, out_act=nn.Tanh) for _ in range(N)]
        self.critics = [mlp(cin, 1) for _ in range(N)]
        self.t_actors, self.t_critics = copy.deepcopy(self.actors), copy.deepcopy(self.critics)
        self.a_opt = [torch.optim.Adam(a.parameters(), lr=1e-3) for a in self.actors]
        self.c_opt = [torch.optim.Adam(c.parameters(), lr=1e-3) for c in self.critics]
        self.teachers = [[mlp(cin, 1) for _ in range(K)] for _ in range(N)]
        self.t_opt = [[torch.optim.Adam(t.parameters(), lr=1e-3) for t in ts] for ts in self.teachers]
        self.phi = [mlp(OD, 32, (64,)) for _ in range(N)]
        self.inv = [mlp(64, AD, (64,)) for _ in range(N)]
        self.fwd = [mlp(32 + AD, 32, (64,)) for _ in range(N)]
        self.i_opt = [
            torch.optim.Adam([*p.parameters(), *g.parameters(), *f.parameters()], lr=1e-3)
            for p, g, f in zip(self.phi, self.inv, self.fwd, strict=True)
        ]

    def td(self, v: int, rew: torch.Tensor, next_obs: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """Agent v's target y [B] from target nets: rew [B, N], next_obs [B, N, OD], done [B]."""
        with torch.no_grad():
            a2 = torch.stack([self.t_actors[u](next_obs[:, u]) for u in range(N)], 1)
            q2 = self.t_critics[v](torch.cat([next_obs.flatten(1), a2.flatten(1)], 1)).squeeze(-1)
            return rew[:, v] + GAMMA * (1 - done) * q2

    def agent_step(self, v: int, b: dict[str, torch.Tensor]) -> None:
        """Critic then actor step of agent v on its own batch b (obs [S, N, OD] ...)."""
        y = self.td(v, b["rew"], b["next_obs"], b["done"])
        q = self.critics[v](torch.cat([b["obs"].flatten(1), b["act"].flatten(1)], 1)).squeeze(-1)
        loss = (y - q).pow(2).mean()
        self.c_opt[v].zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(self.critics[v].parameters(), CLIP)
        self.c_opt[v].step()
        act = b["act"].clone()
        act[:, v] = self.actors[v](b["obs"][:, v])
        a_loss = -self.critics[v](torch.cat([b["obs"].flatten(1), act.flatten(1)], 1)).mean()
        self.a_opt[v].zero_grad()
        a_loss.backward()
        nn.utils.clip_grad_norm_(self.actors[v].parameters(), CLIP)
        self.a_opt[v].step()

    def soft_update(self) -> None:
        with torch.no_grad():
            for src, tgt in zip([*self.actors, *self.critics], [*self.t_actors, *self.t_critics], strict=True):
                for s, t in zip(src.parameters(), tgt.parameters(), strict=True):
                    t.mul_(1 - TAU).add_(s, alpha=TAU)

    def teacher_step(self, a: int, i: int, rows_t: dict[str, torch.Tensor], idx: np.ndarray) -> None:
        b = {k: v[idx] for k, v in rows_t.items()}
        y = self.td(a, b["rew"], b["next_obs"], b["done"])
        pred = self.teachers[a][i](torch.cat([b["obs"].flatten(1), b["act"].flatten(1)], 1)).squeeze(-1)
        loss = (pred - y).pow(2).mean()
        self.t_opt[a][i].zero_grad()
        loss.backward()
        self.t_opt[a][i].step()

    def icm_step(self, a: int, o: torch.Tensor, act: torch.Tensor, o2: torch.Tensor) -> None:
        f, f2 = self.phi[a](o), self.phi[a](o2)
        inv = (torch.tanh(self.inv[a](torch.cat([f, f2], 1))) - act).pow(2).sum(1).mean()
        fwd = 0.5 * (self.fwd[a](torch.cat([f, act], 1)) - f2).pow(2).sum(1).mean()
        self.i_opt[a].zero_grad()
        (0.8 * inv + 0.2 * fwd).backward()
        self.i_opt[a].step()

    def update(self, rows: dict, fold: np.ndarray, rng: np.random.Generator) -> None:
        rows_t = {k: torch.from_numpy(v) for k, v in rows.items()}
        idx = rng.integers(0, M, size=(N, S))
        for v in range(N):
            self.agent_step(v, {k: t[idx[v]] for k, t in rows_t.items()})
        self.soft_update()
        tidx = fold_draw_indices(fold, range(K), S, rng, draws=N)[0]  # [N, K, S]
        for a in range(N):
            for i in range(K):
                self.teacher_step(a, i, rows_t, tidx[a, i])
        j = rng.integers(0, M, size=S)
        for a in range(N):
            self.icm_step(a, rows_t["obs"][j, a], rows_t["act"][j, a], rows_t["next_obs"][j, a])

    @torch.no_grad()
    def rescore(self, rows: dict, fold: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = {k: torch.from_numpy(v) for k, v in rows.items()}
        x = torch.cat([r["obs"].flatten(1), r["act"].flatten(1)], 1)
        c = np.zeros((N, M), np.float32)
        rho = np.zeros((N, M), np.float32)
        for a in range(N):
            y = self.td(a, r["rew"], r["next_obs"], r["done"])
            for i in range(K):
                e = (y - self.teachers[a][i](x).squeeze(-1)).pow(2).numpy()
                c[a] += np.where(fold != i, e, 0.0)
            pred = self.fwd[a](torch.cat([self.phi[a](r["obs"][:, a]), r["act"][:, a]], 1))
            rho[a] = (0.5 * (pred - self.phi[a](r["next_obs"][:, a])).pow(2).sum(1)).numpy()
        return c, rho


# ----------------------------------------------------------------------------- timing
def time_round(impl, rows, fold, rng, n: int) -> float:
    """Updates per second over n updates."""
    t0 = time.perf_counter()
    for _ in range(n):
        impl.update(rows, fold, rng)
    return n / (time.perf_counter() - t0)


def time_rescore(impls, rows, fold, reps: int = 5) -> list[float]:
    """Best-of-reps seconds per full-buffer rescoring for each implementation (interleaved)."""
    best = [float("inf")] * len(impls)
    for _ in range(reps):
        for k, impl in enumerate(impls):
            t0 = time.perf_counter()
            impl.rescore(rows, fold)
            best[k] = min(best[k], time.perf_counter() - t0)
    return best


def main() -> None:
    torch.set_num_threads(1)
    rows, fold = make_buffer()
    ours, peer = Ours(), Peer()
    rng_o, rng_p = np.random.default_rng(1), np.random.default_rng(1)
    time_round(ours, rows, fold, rng_o, 3)  # warm-up
    time_round(peer, rows, fold, rng_p, 3)
    r_o, r_p = [], []
    for _ in range(ROUNDS):
        r_o.append(time_round(ours, rows, fold, rng_o, UPDATES_PER_ROUND))
        r_p.append(time_round(peer, rows, fold, rng_p, UPDATES_PER_ROUND))
    u_o, u_p = statistics.median(r_o), statistics.median(r_p)
    s_o, s_p = time_rescore([ours, peer], rows, fold)
    print(f"setup: N={N} agents, obs_dim={OD}, act_dim={AD}, batch={S}, K={K} teachers/agent, 1 thread")
    print(f"full CMCL update  ours (stacked): {u_o:8.1f} updates/s   ({1e3 / u_o:6.2f} ms)")
    print(f"full CMCL update  peer (loops):   {u_p:8.1f} updates/s   ({1e3 / u_p:6.2f} ms)")
    print(f"rescore {M} rows  ours: {1e3 * s_o:7.1f} ms   peer: {1e3 * s_p:7.1f} ms   ({s_p / s_o:.2f}x)")
    print(f"ratio: {u_o / u_p:.2f}")
    cost = cmcl_vs_maddpg_cost()
    print(f"cmcl/maddpg cost: {cost:.2f}")


# ----------------------------------------------------------------------------- CMCL vs MADDPG, as the runners run them
class FilledRoles:
    """The service's roles of one config built in this process (as `--runner inline` builds them: every teacher
    fold in one stacked worker), the replay buffer filled to its capacity by the rollout worker's policy. `update()`
    is what the supervisor hands out per `service.updates_per_call` learner updates: one learner call (the replay's
    sample, the MADDPG steps, the |δ| written back) and the teacher / ICM calls that the ratios
    (`teachers.steps_per_update`, `icm.steps_per_update`) owe for those updates, each of `service.fit_steps_per_call`
    fit steps and the scoring of `service.score_rows_per_call` rows, their scores written back; returns the number
    of learner updates it ran."""

    def __init__(self, config):
        from services.roles.icm import ICMWorker
        from services.roles.learner import Learner
        from services.roles.replay_server import ReplayServer
        from services.roles.rollout import RolloutWorker
        from services.roles.teachers import TeacherWorker

        self.config = config
        cfg = config.to_dict()
        teams = config.teams.values()
        self.replay, self.learner = ReplayServer(cfg), Learner(cfg, 0)
        self.maddpg = self.learner.maddpg
        folds = list(range(config.teachers.num_folds))
        self.teacher = TeacherWorker(cfg, folds, 1) if any(t.uses_teachers for t in teams) else None
        self.icm = ICMWorker(cfg, 2) if any(t.uses_icm for t in teams) else None
        self.teachers = None if self.teacher is None else self.teacher.teachers  # the ensemble of every fold
        self.folds = folds
        worker = RolloutWorker(cfg, 0, 0)
        while self.replay.replay.size < self.replay.replay.capacity:
            self.replay.insert(worker.rollout(self.learner.publish())[0])
        self.published = self.learner.publish()
        s = config.service
        self.teacher_calls = config.teachers.steps_per_update * s.updates_per_call / s.fit_steps_per_call
        self.icm_calls = config.icm.steps_per_update * s.updates_per_call / s.fit_steps_per_call
        self.owed = {"teacher": 0.0, "icm": 0.0}

    def update(self) -> int:
        s = self.config.service
        batch, _ = self.replay.sample(s.updates_per_call)
        feedback, _ = self.learner.update(batch)
        self.replay.learner_result(feedback)
        if self.teacher is not None:
            self.owed["teacher"] += self.teacher_calls
            while self.owed["teacher"] >= 1:
                work, _ = self.replay.work(Scorer(DIFFICULTY, tuple(self.folds)), s.fit_steps_per_call)
                self.replay.write(self.teacher.score(work, self.published)[0])
                self.owed["teacher"] -= 1
        if self.icm is not None:
            self.owed["icm"] += self.icm_calls
            while self.owed["icm"] >= 1:
                work, _ = self.replay.work(Scorer(CURIOSITY), s.fit_steps_per_call)
                self.replay.write(self.icm.score(work)[0])
                self.owed["icm"] -= 1
        return s.updates_per_call


def filled_loop(algorithm: str, overrides: list[str] = ()) -> FilledRoles:
    """The roles of the default spread preset for `algorithm` (plus config `overrides`), its 5000-row buffer filled
    by the policy (`FilledRoles`)."""
    config = load_config(f"{ROOT}/configs/spread_{algorithm}.toml",
                         ["run.dir=unused", "maddpg.warmup=5000", *overrides])
    return FilledRoles(config)


def inline_update_seconds(rounds: int = 7, updates: int = 32) -> tuple[dict[str, float], FilledRoles]:
    """({"maddpg": s, "cmcl": s}: median seconds of one learner update of each with what the runners do for it,
    interleaved rounds of about `updates` updates; the CMCL roles).

    A CMCL update here is everything the roles do per update at the defaults: the teacher and ICM fit steps due at
    their ratios with their scoring calls, the priority recompute of the sampling, the MADDPG step (`FilledRoles`).
    Seconds are this process's CPU seconds (one thread: the time the roles ran, without a shared core's waits).
    """
    loops = {name: filled_loop(name) for name in ("maddpg", "cmcl")}
    seconds: dict[str, list[float]] = {name: [] for name in loops}
    for _ in range(rounds):
        for name, loop in loops.items():
            t0, done = time.process_time(), 0
            while done < updates:
                done += loop.update()
            seconds[name].append((time.process_time() - t0) / done)
    return {name: statistics.median(v) for name, v in seconds.items()}, loops["cmcl"]


def cmcl_vs_maddpg_cost(rounds: int = 7, updates: int = 32) -> float:
    """Median seconds of one learner update of CMCL over one of MADDPG (`inline_update_seconds`)."""
    per, cmcl = inline_update_seconds(rounds, updates)
    s = cmcl.config.service
    print(f"one update at the defaults (CPU time): maddpg {1e3 * per['maddpg']:.2f} ms, "
          f"cmcl {1e3 * per['cmcl']:.2f} ms "
          f"(teachers {cmcl.config.teachers.steps_per_update:g} / ICM "
          f"{cmcl.config.icm.steps_per_update:g} steps per update, calls of {s.updates_per_call} updates / "
          f"{s.fit_steps_per_call} fit steps / {s.score_rows_per_call} rows scored)")
    return per["cmcl"] / per["maddpg"]


if __name__ == "__main__":
    main()
