"""Evaluate a trained run: coverage, success, reward and win rate over n episodes; a GIF; the learning curve.

Where it sits: read-only consumer of a run directory written by either runner. Policies act
without exploration noise in the batched twin (statistics) and in the PettingZoo env (the GIF).

Run:  python -m cmcl evaluate runs/spread_cmcl [--episodes 100] [--checkpoint PATH] [--gif out.gif]
      python -m cmcl evaluate runs/spread_cmcl --random      (the random-policy reference on the same worlds)
`python -m cmcl.run.evaluate RUN_DIR ...` is the same command under its older name.
"""

from __future__ import annotations

import argparse
import errno
import io
import json
import os
import stat
import sys
import tempfile
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from cmcl.config import Config
from cmcl.envs.batched_spread import BatchedSparseSpread
from cmcl.io.atomic import atomic_write_bytes
from cmcl.io.checkpoint_files import load_checkpoint
from cmcl.io.write_failure import RunWriteError
from cmcl.learners.maddpg import MADDPG
from cmcl.run.flags import add_evaluate_flags
from cmcl.run.rundir import PolicyCheckpoint, RunDirectory
from cmcl.run.stalls import MissAnatomy, miss_anatomy
from cmcl.run.stopping import exit_without_teardown
from cmcl.system import (
    acts_discretely,
    build_maddpg,
    layout_of,
    make_batched_env,
    make_parallel_env,
    to_env_actions,
)

EVAL_SEED_OFFSET = 10_000  # evaluation worlds never reuse the training seed's worlds


MEASURES = ("coverage", "success", "collisions", "wall_hits", "predator_win")  # an evaluation's named measures
SATURATED = 0.99  # |a| at or beyond it: a tanh action at its bound
SATURATION_WARNING = 0.5  # the share of saturated action entries from which the report warns


def measures_text(result: dict[str, Any], keys: tuple[str, ...] | list[str]) -> str:
    """'coverage 0.512, success 0.100, return[agent] 12.3': the `keys` of an evaluation `result` (`evaluate_policy`),
    then each team's return (any environment)."""
    return ", ".join([*(f"{k} {result[k]:.3f}" for k in keys),
                      *(f"return[{team}] {value:.1f}" for team, value in result["reward"].items())])


def beside_random(trained: dict[str, Any], random: dict[str, Any], episodes: int) -> str:
    """The held-out evaluation line: the policy's measures beside the random policy's on the same `episodes`
    worlds (train's end and a standalone `evaluate` print it alike)."""
    keys = [k for k in MEASURES if k in trained]
    return (f"held-out evaluation ({episodes} new worlds, no exploration noise): {measures_text(trained, keys)}"
            f"  | random policy: {measures_text(random, keys)}")


def load_policy(config: Config, checkpoint: PolicyCheckpoint | str | Path) -> MADDPG:
    """MADDPG with the weights of `checkpoint`: a run's `PolicyCheckpoint` (already verified and decoded), or a
    file (checked against its `.sha256` manifest when it has one; torch.load(weights_only=True))."""
    maddpg = build_maddpg(config, layout_of(config), seed=0)
    state = checkpoint.state if isinstance(checkpoint, PolicyCheckpoint) else load_checkpoint(checkpoint)
    maddpg.load_state_dict(state["maddpg"])
    return maddpg


def evaluate_policy(config: Config, maddpg: MADDPG | None, episodes: int = 100, seed: int = 0,
                    noise_std: float = 0.0, random_teams: tuple[str, ...] = ()) -> dict[str, Any]:
    """Run `episodes` episodes in parallel in the batched twin; maddpg=None acts uniformly at random.

    random_teams: teams whose agents act uniformly at random while the others use `maddpg` (e.g. ("prey",) to
    pit trained predators against random prey). Returns means and standard deviations over episodes: coverage
    (final step), success, collisions, predator_win, the team returns {team: mean}, and in navigation "misses":
    where the final step misses landmarks (`cmcl.run.stalls.MissAnatomy` as a dict). A trained continuous policy
    also gives "saturated_actions": the share of its agents' action entries with |a| >= SATURATED over every step
    of the worlds still playing (near 1: the actors push every action to the bound, as unregularised tanh actors do
    when the critic's gradient says little).
    """
    torch.set_num_threads(1)
    rng = np.random.default_rng(seed + EVAL_SEED_OFFSET)
    env = make_batched_env(config, num_envs=episodes, seed=rng, auto_reset=False)
    unknown = sorted(set(random_teams) - set(env.teams))
    if unknown:
        raise ValueError(f"random_teams names {unknown[0]!r}, not a team of this task: {sorted(env.teams)}")
    random_agents = [a for team in random_teams for a in env.teams[team]]
    obs = env.reset()
    ended, parts = np.zeros(episodes, bool), []  # parts: info["episode"] of the steps in which worlds ended
    own = np.setdiff1d(np.arange(env.num_agents), random_agents)  # the trained agents
    continuous = not acts_discretely(config, env)
    at_bound = []  # per step, continuous policies: the share of the trained agents' action entries at the bound
    for _ in range(env.episode_length):  # the twins end every world at the last step; an env.factory world any time
        uniform = rng.uniform(-1.0, 1.0, size=(episodes, env.num_agents, env.act_dim)).astype(np.float32)
        if maddpg is None:
            actions = uniform
        else:
            actions = to_env_actions(maddpg.act(obs, noise_std, rng=rng), config.maddpg.discrete)
            if continuous and own.size and not ended.all():
                at_bound.append(float((np.abs(actions[~ended][:, own]) >= SATURATED).mean()))
            actions[:, random_agents] = uniform[:, random_agents]
        obs, _, done, info = env.step(actions)
        if done.any():
            parts.append(info["episode"])
            ended |= done
        if ended.all():
            break
    ep = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    out: dict[str, Any] = {"episodes": episodes, "policy": "random" if maddpg is None else "trained"}
    if isinstance(env, BatchedSparseSpread):  # where the landmarks were missed (cmcl.run.stalls)
        state = env.get_state()
        out["misses"] = asdict(miss_anatomy(state["positions"], state["landmarks"], env.params.cover_radius,
                                            env.params.agent_radius))
    for key in ("coverage", "success", "collisions", "wall_hits", "captures", "predator_win"):
        if key in ep:
            values = np.asarray(ep[key], dtype=np.float64)
            out[key], out[f"{key}_std"] = float(values.mean()), float(values.std())
    out["reward"] = {team: float(ep["return"][:, idx].sum(1).mean()) for team, idx in env.teams.items()}
    if at_bound:
        out["saturated_actions"] = float(np.mean(at_bound))
    return out


def saturation_line(result: dict[str, Any]) -> str:
    """A warning when a held-out evaluation's actions sit at their bound (`saturated_actions` >= SATURATION_WARNING),
    else ''."""
    share = result.get("saturated_actions", 0.0)
    if share < SATURATION_WARNING:
        return ""
    return (f"warning: {share:.0%} of the trained actions are at their bound (|a| >= {SATURATED}): the actors' tanh "
            "is saturated, each agent pushing as hard as it can whatever it sees. On a sparse reward this is what a "
            "critic that has seen little reward teaches; a smaller maddpg.gamma and a larger replay.capacity let the "
            "first rewards count (docs/SPARSE_TASKS.md)")


def render_gif(config: Config, maddpg: MADDPG | None, path: str | Path, seed: int = 0, fps: int = 10) -> Path:
    """One episode of the PettingZoo env with the policy (no noise; random if maddpg is None) as a GIF at `path`,
    written atomically (a full disk: RunWriteError naming the file)."""
    atomic_write_bytes(path, gif_bytes(config, maddpg, seed, fps))
    return Path(path)


def headless_sdl() -> None:
    """Before an environment's pygame renders off screen: SDL's dummy video and audio drivers (unless set), and a
    private XDG_RUNTIME_DIR (mode 0700) when the one set is missing or not a folder of this user's, so that SDL
    prints no "error: XDG_RUNTIME_DIR is invalid or not set" after a GIF that was written."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
    runtime = os.environ.get("XDG_RUNTIME_DIR", "")
    try:
        info = os.stat(runtime) if runtime else None
    except OSError:
        info = None
    if info is None or not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid() or info.st_mode & 0o077:
        os.environ["XDG_RUNTIME_DIR"] = tempfile.mkdtemp(prefix="cmcl-xdg-")  # mkdtemp makes it 0700


def gif_bytes(config: Config, maddpg: MADDPG | None, seed: int = 0, fps: int = 10) -> bytes:
    """One episode of the PettingZoo env with the policy (no noise; random if maddpg is None), encoded as a GIF."""
    from PIL import Image

    headless_sdl()
    if config.env.factory:
        frames = _factory_frames(config, maddpg, seed)
    else:
        frames = _twin_frames(config, maddpg, seed)
    images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
    encoded = io.BytesIO()
    images[0].save(encoded, format="GIF", save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return encoded.getvalue()


def gif_line(config: Config, maddpg: MADDPG | None, path: str | Path, seed: int = 0) -> str:
    """The line that ends an evaluation: "gif: PATH"; when the environment cannot draw itself here (a headless
    machine without the OpenGL MuJoCo needs, a render that returns nothing, ...), why there is no GIF; when the file
    cannot be written (a full disk, a folder that cannot be made), that it is not written and why. The GIF is an
    extra: neither failure fails the evaluation or the run before it."""
    try:
        encoded = gif_bytes(config, maddpg, seed)
    except Exception as err:  # noqa: BLE001 - any failure of the env's own render, reported, never fatal
        why = f"{type(err).__name__}: {err}" if str(err).strip() else f"{type(err).__name__}, raised without a message"
        return f"gif: none, the environment could not render here ({why})"
    try:
        atomic_write_bytes(path, encoded)
    except RunWriteError as err:  # a full disk: the line says so, the evaluation before it stands
        return f"gif: not written ({err})"
    except OSError as err:  # a path that cannot be written (no such folder, no permission): named as such
        # mkdir of a parent that is a file says "File exists" (EEXIST), of one under a file ENOTDIR: said plainly
        why = "a folder on its path is a file" if err.errno in (errno.EEXIST, errno.ENOTDIR) else err.strerror or err
        return f"gif: not written (cannot write {path}: {why})"
    return f"gif: {path}"


def _factory_frames(config: Config, maddpg: MADDPG | None, seed: int) -> list[Any]:
    """Frames of one episode of an env.factory environment (its own `render`), stepped through the adapter."""
    rng = np.random.default_rng(seed + EVAL_SEED_OFFSET)
    env = make_batched_env(config, num_envs=1, seed=rng, auto_reset=False, render_mode="rgb_array")
    obs, frames, done = env.reset(), [env.render()], np.zeros(1, bool)
    if frames[0] is None:
        raise ValueError(f"env.factory {config.env.factory!r}: render() returned no frame with "
                         "render_mode='rgb_array', so there is no GIF")
    while not done[0]:
        actions = rng.uniform(-1.0, 1.0, size=(1, env.num_agents, env.act_dim)).astype(np.float32) \
            if maddpg is None else maddpg.act(obs, 0.0, rng=rng)
        obs, _, done, _ = env.step(actions)
        frames.append(env.render())
    env.close()
    return frames


def _twin_frames(config: Config, maddpg: MADDPG | None, seed: int) -> list[Any]:
    """Frames of one episode of the built-in task's PettingZoo env."""
    env = make_parallel_env(config, render_mode="rgb_array")
    rng = np.random.default_rng(seed + EVAL_SEED_OFFSET)
    observations, _ = env.reset(seed=seed + EVAL_SEED_OFFSET)
    obs_dim = max(env.observation_space(a).shape[0] for a in env.possible_agents)
    frames = [env.render()]
    while env.agents:
        if maddpg is None:
            acts = {a: env.action_space(a).sample() for a in env.agents}
        else:
            obs = np.zeros((1, len(env.possible_agents), obs_dim), np.float32)
            for i, agent in enumerate(env.possible_agents):
                obs[0, i, : observations[agent].shape[0]] = observations[agent]
            joint = to_env_actions(maddpg.act(obs, 0.0, rng=rng), config.maddpg.discrete)[0]
            acts = {agent: joint[i] for i, agent in enumerate(env.possible_agents)}
        observations, *_ = env.step(acts)
        frames.append(env.render())
    env.close()
    return frames


def main(argv: list[str] | None = None) -> int:
    """`python -m cmcl.run.evaluate RUN_DIR`: the alias of `python -m cmcl evaluate RUN_DIR` (same flags)."""
    return evaluate_run(build_parser().parse_args(argv))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m cmcl.run.evaluate", description=__doc__.split("\n")[0])
    add_evaluate_flags(parser)
    return parser


def evaluate_run(args: argparse.Namespace) -> int:
    """Evaluate the newest verified (or a given) checkpoint of a run, write a GIF and the learning curve; `args` as
    `cmcl.run.flags.add_evaluate_flags` defines them. Exit codes: 0 done, 2 bad arguments or no run / policy. A run
    directory this process cannot write to is only read: the GIF (unless --gif names another place) and the learning
    curve are then not written, said in one line each."""
    from cmcl.run.preflight import check_worlds_fit

    if args.episodes < 1:
        print(f"error: --episodes must be >= 1, got {args.episodes}", file=sys.stderr)
        return 2
    try:
        run = RunDirectory.open(args.run_dir)
        config = run.config()
        check_worlds_fit(config, args.episodes, "--episodes")
        checkpoint: PolicyCheckpoint | Path | None = None
        if args.checkpoint:
            checkpoint = Path(args.checkpoint)
            if not checkpoint.is_file():
                raise FileNotFoundError(f"--checkpoint {args.checkpoint}: no such file")
        elif not args.random:
            checkpoint = run.newest_policy()
            if checkpoint is None:
                raise FileNotFoundError(f"no checkpoint that passes its checks in {args.run_dir} (pass --checkpoint "
                                        "or --random)")
            if run.refused_policies:
                print(f"note: evaluating {checkpoint.path}, an older checkpoint: refused "
                      f"{'; '.join(run.refused_policies)}", file=sys.stderr)
        maddpg = None if args.random or checkpoint is None else load_policy(config, checkpoint)
        episode_rows = sum(1 for _ in run.rows("episode"))  # a corrupt metrics file is refused before any work
    except (FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except Exception as err:  # noqa: BLE001 - a verified file, not a policy: torch.load's UnpicklingError, KeyError, ...
        why = f"{type(err).__name__}: {str(err).strip().split('. ')[0]}" if str(err).strip() else type(err).__name__
        print(f"error: --checkpoint {args.checkpoint} is not a policy checkpoint of this run ({why})", file=sys.stderr)
        return 2
    result = evaluate_policy(config, maddpg, args.episodes, args.seed)
    result["checkpoint"] = None if maddpg is None else str(getattr(checkpoint, "path", checkpoint))
    random = None if maddpg is None else evaluate_policy(config, None, args.episodes, args.seed)
    if random is not None:  # the baseline train prints too, on the same worlds
        result["random_policy"] = {key: value for key, value in random.items() if key != "misses"}
    print(json.dumps(result, indent=2))
    if random is not None:
        print(beside_random(result, random, args.episodes), file=sys.stderr)  # stdout stays JSON
    if "misses" in result:
        print("\n".join(MissAnatomy(**result["misses"]).lines()), file=sys.stderr)
    saturated = saturation_line(result)
    if saturated:
        print(saturated, file=sys.stderr)
    out_dir = _output_dir(run.path)
    writable = out_dir != run.path or _writable(run.path)
    if not args.no_gif:
        if args.gif or writable:
            print(gif_line(config, maddpg, args.gif or out_dir / ("eval_random.gif" if args.random else "eval.gif"),
                           args.seed))
        else:
            print(f"gif: not written, {run.path} is read-only (pass --gif PATH to write it elsewhere)")
    from cmcl.run.plots import curve_line

    if episode_rows:
        if writable:
            print(curve_line([run.path], out_dir / "learning_curve.png"))
        else:
            print(f"learning curve: not written, {run.path} is read-only")
    return 0


def _output_dir(run_path: Path) -> Path:
    """Where evaluate writes its GIF and learning curve: the run directory, unless another process holds it (a run
    training there, `cmcl.run.runlock`): then a new folder under the system's temporary directory, said on stderr."""
    from cmcl.run.runlock import holder_of

    holder = holder_of(run_path)
    if holder is None:
        return run_path
    elsewhere = Path(tempfile.mkdtemp(prefix="cmcl-evaluate-"))
    print(f"note: {run_path} is in use ({holder}), so evaluate writes nothing there: its GIF and learning curve go "
          f"to {elsewhere}", file=sys.stderr)
    return elsewhere


def _writable(directory: Path) -> bool:
    """Whether this process can create a file in `directory` (tried: a read-only mount, permissions)."""
    try:
        with tempfile.TemporaryFile(dir=directory):
            return True
    except OSError:
        return False


if __name__ == "__main__":
    exit_without_teardown(main())  # the exit status of sys.exit, without ~1-2 s of teardown
