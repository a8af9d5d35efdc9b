"""Launch the distributed CMCL service: embedded Ray by default, or join a cluster with --address auto.

    python -m services.launch [--config F] [--set section.key=value ...] [--address auto]
                              [--metrics-port P] [--metrics-host H] [--resume DIR] [--num-cpus N]

Where it sits: the entry point. It validates the config, starts (or joins) Ray, opens the Prometheus endpoint,
creates every role (services.placement.create_roles) and runs the supervisor loop until run.episodes episodes
(or run.max_seconds), then checkpoints, writes the learning curve and shuts down cleanly.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from cmcl.config import Config, ConfigError, load_config
from cmcl.io.rundir import RunDirectory


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m services.launch", description=__doc__.split("\n")[0])
    parser.add_argument("--config", help="TOML experiment file (default: built-in CMCL defaults)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override one config value (repeatable)")
    parser.add_argument("--address", default=None,
                        help="Ray cluster to join ('auto' after `ray start --head`); default: embedded Ray")
    parser.add_argument("--num-cpus", type=int, default=None, help="CPUs of the embedded Ray (default: all)")
    parser.add_argument("--metrics-port", type=int, default=None, help="Prometheus port (default service.metrics_port)")
    parser.add_argument("--metrics-host", default=None, help="bind address (default 127.0.0.1, loopback only)")
    parser.add_argument("--ray-metrics-port", type=int, default=None,
                        help="embedded Ray only: port of Ray's own Prometheus metrics (default: Ray picks one)")
    parser.add_argument("--resume", metavar="DIR", help="continue the run in DIR from its service checkpoint")
    parser.add_argument("--overwrite", action="store_true", help="start over in a run.dir that holds a run")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.add_argument("--no-eval", action="store_true",
                        help="skip the held-out evaluation, the GIF and the learning curve at the end")
    return parser.parse_args(argv)


def resolve(args: argparse.Namespace) -> tuple[Config, RunDirectory]:
    """Config (file + overrides + CLI metrics flags) and the run directory (new, or the one resumed)."""
    extra = list(args.overrides)
    if args.metrics_port is not None:
        extra.append(f"service.metrics_port={args.metrics_port}")
    if args.metrics_host is not None:
        extra.append(f'service.metrics_host="{args.metrics_host}"')
    if args.resume:
        run_dir = RunDirectory.open(args.resume)
        return run_dir.config(tuple(extra)), run_dir
    config = load_config(args.config, extra)
    return config, RunDirectory.create(config.run.dir, config, overwrite=args.overwrite)


def start_ray(address: str | None, num_cpus: int | None, metrics_export_port: int | None = None) -> None:
    """Join `address`, or start an embedded Ray sized to this machine (no dashboard)."""
    import ray

    os.environ.setdefault("RAY_DEDUP_LOGS", "0")
    if ray.is_initialized():
        return
    if address:
        try:
            ray.init(address=address, log_to_driver=False)
        except (ConnectionError, RuntimeError, ValueError) as err:
            raise ConnectionError(f"cannot join the Ray cluster at --address {address}: {err}. Start one with "
                                  f"`ray start --head`, or omit --address for an embedded Ray") from None
        return
    ray.init(address="local", num_cpus=num_cpus or os.cpu_count(), include_dashboard=False, log_to_driver=False,
             _metrics_export_port=metrics_export_port)


def run_service(config: Config, run_dir: RunDirectory, *, resume: bool = False, progress: Any = print
                ) -> dict[str, Any]:
    """Run the service on the Ray already initialised; returns the supervisor's final summary."""
    from services.metrics import ServiceMetrics
    from services.placement import create_roles
    from services.supervisor import Supervisor

    metrics = ServiceMetrics(seed=config.run.seed)
    port = metrics.serve(config.service.metrics_port, config.service.metrics_host)
    try:
        if progress is not None:
            progress(f"metrics: http://{config.service.metrics_host}:{port}/metrics   run directory: {run_dir.path}")
        roles = create_roles(config, run_dir)
        supervisor = Supervisor(config, run_dir, roles, metrics, progress=progress)
        if resume:
            supervisor.restore_counters()
        summary = supervisor.run()
        summary["metrics_port"] = port
        summary["metrics_text"] = metrics.text()
        return summary
    finally:
        metrics.close()


def main(argv: list[str] | None = None) -> int:
    """CLI entry point. Exit codes: 0 done, 2 bad config / arguments / cluster / resources."""
    args = parse_args(argv)
    try:
        config, run_dir = resolve(args)
    except (ConfigError, FileExistsError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    import ray

    from services.placement import InfeasibleResources

    try:
        start_ray(args.address, args.num_cpus, args.ray_metrics_port)
    except ConnectionError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    try:
        summary = run_service(config, run_dir, resume=bool(args.resume), progress=None if args.quiet else print)
    except InfeasibleResources as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    finally:
        ray.shutdown()
    print(f"done: {summary['episodes']} episodes, {summary['env_steps']} env steps, {summary['updates']} updates "
          f"in {summary['elapsed_s']:.0f}s" + (f" (coverage target {config.run.stop_coverage} reached)"
                                               if summary.get("solved") else ""))
    if not args.no_eval:
        report_trained(config, run_dir)
    return 0


def report_trained(config: Config, run_dir: RunDirectory, episodes: int = 200) -> None:
    """Held-out evaluation of the learner's final weights (no exploration noise, worlds never trained on), a GIF of
    one episode and the learning curve, all in the run directory."""
    from cmcl.evaluate import evaluate_policy, load_policy, render_gif
    from cmcl.io.plots import plot_learning_curves

    if any(True for _ in run_dir.rows("episode")):
        window = min(config.run.smoothing_window, max(1, config.run.episodes // 10))
        png = plot_learning_curves([run_dir.path], run_dir.path / "learning_curve.png", window=window)
        print(f"learning curve: {png}")
    learner = run_dir.checkpoints / "service" / "learner.pt"
    if not learner.is_file():
        return
    policy = load_policy(config, learner)
    trained, random = evaluate_policy(config, policy, episodes), evaluate_policy(config, None, episodes)
    keys = [k for k in ("coverage", "success", "collisions", "wall_hits", "predator_win") if k in trained]
    print(f"held-out evaluation ({episodes} new worlds, no exploration noise): "
          + ", ".join(f"{k} {trained[k]:.3f}" for k in keys)
          + "  | random policy: " + ", ".join(f"{k} {random[k]:.3f}" for k in keys))
    print(f"gif: {render_gif(config, policy, run_dir.path / 'trained.gif')}")


if __name__ == "__main__":
    sys.exit(main())
