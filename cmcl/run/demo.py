"""Random-policy demo of the two sparse worlds: episode statistics and one GIF per task.

Where it sits: a smoke check of `cmcl.envs` a person can run and look at (no training). Statistics
come from the batched twins (all episodes stepped at once); one episode of each PettingZoo version
is rendered (render_mode="rgb_array", walls drawn) and written as a GIF with pillow. Headless.

    python -m cmcl.run.demo [--episodes 20] [--gif-dir runs/demo] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")


def batched_stats(task: str, episodes: int, rng: np.random.Generator) -> dict[str, float]:
    """Run `episodes` random-policy episodes of the batched twin at once; return averaged statistics."""
    from cmcl.envs.batched import BatchedSparseSpread, BatchedSparseTag

    cls = BatchedSparseSpread if task == "spread" else BatchedSparseTag
    env = cls(episodes, seed=rng)
    dones = np.zeros(episodes, dtype=bool)
    while not dones.all():
        _, _, dones, info = env.step(rng.uniform(-1.0, 1.0, (episodes, env.num_agents, env.act_dim)))
    ep = info["episode"]
    if task == "spread":
        return {
            "coverage (final step)": float(ep["coverage"].mean()),
            "success rate": float(ep["success"].mean()),
            "collisions / episode": float(ep["collisions"].mean()),
            "wall hits / episode": float(ep["wall_hits"].mean()),
            "team return (unshared)": float(ep["return"].sum(axis=1).mean()),
        }
    prey = env.teams["prey"]
    return {
        "captures / episode": float(ep["captures"].mean()),
        "predator win rate": float(ep["predator_win"].mean()),
        "wall hits / episode": float(ep["wall_hits"].mean()),
        "prey return": float(ep["return"][:, prey].sum(axis=1).mean()),
    }


def render_gif(task: str, path: Path, seed: int) -> Path:
    """Render one random-policy episode of the PettingZoo version into a GIF at `path`."""
    from PIL import Image

    from cmcl.envs import sparse_spread_v0, sparse_tag_v0

    module = sparse_spread_v0 if task == "spread" else sparse_tag_v0
    env = module.parallel_env(render_mode="rgb_array")
    env.reset(seed=seed)
    for i, agent in enumerate(env.possible_agents):
        env.action_space(agent).seed(seed + i)
    frames = [env.render()]
    while env.agents:
        env.step({a: env.action_space(a).sample() for a in env.agents})
        frames.append(env.render())
    env.close()
    images = [Image.fromarray(f) for f in frames]
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(path, save_all=True, append_images=images[1:], duration=100, loop=0)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20, help="random-policy episodes per task (>= 1)")
    parser.add_argument("--gif-dir", type=Path, default=Path("runs/demo"), help="where the GIFs go")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    rng = np.random.default_rng(args.seed)
    for task in ("spread", "tag"):
        start = time.perf_counter()
        print(f"[{task}] {args.episodes} random-policy episodes on the batched twin ...", flush=True)
        stats = batched_stats(task, args.episodes, rng)
        for key, value in stats.items():
            print(f"[{task}]   {key:24s} {value:8.3f}")
        gif = render_gif(task, args.gif_dir / f"sparse_{task}_random.gif", args.seed)
        print(f"[{task}] GIF: {gif}  ({time.perf_counter() - start:.1f} s)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
