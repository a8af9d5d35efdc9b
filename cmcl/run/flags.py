"""The command-line flags of a training run, defined once for every entry point, the typed request they become, and
the opening of the run directory that request names (the same for both runners).

Where it sits: `python -m cmcl train | resume` (cmcl/__main__.py) and its alias `python -m services.launch` (either
runner) build their parsers here, so both accept the
same flags and cannot drift (tests/test_cli.py checks it). Each parser's namespace becomes a `RunRequest`, which is
what a runner receives; `add_evaluate_flags` does the same for `python -m cmcl evaluate` and `python -m
cmcl.run.evaluate`. This module imports neither a runner, torch nor Ray: `--help` stays fast and `cmcl/` stays free of
Ray.
"""

from __future__ import annotations

import argparse
import dataclasses
import errno
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, get_args

from cmcl.config import Config, ConfigError, apply_overrides, config_from_dict, dump_toml, load_data
from cmcl.config.runners import Runner, check_runner_keys
from cmcl.config.toml_io import parse_override
from cmcl.config.world_keys import check_world_keys
from cmcl.envs.factory import EnvFactoryError
from cmcl.io.atomic import atomic_write_bytes
from cmcl.io.metrics_log import MetricsError
from cmcl.io.resume_hint import resume_command
from cmcl.io.verified import CheckpointError
from cmcl.io.write_failure import RunWriteError, write_failure_line
from cmcl.replay.registry import uses_lambda
from cmcl.run.rundir import ForeignFolderError, RunDirectory
from cmcl.run.runlock import RunDirectoryInUse, RunLock, holder_command

RUNNERS: tuple[str, ...] = get_args(Runner)
# the inline runner serves no metrics and starts no Ray: these flags are the service's only (flags, not config
# keys: cmcl.config.runners says why RUNNER_ONLY is another table)
SERVICE_ONLY_FLAGS = {"address": "--address", "num_cpus": "--num-cpus", "ray_metrics_port": "--ray-metrics-port",
                      "metrics_port": "--metrics-port", "metrics_host": "--metrics-host"}
# the last commit whose inline runner wrote and resumed checkpoints of its own format (checkpoints/ckpt_*.pt); since,
# both runners write the service's (each role's verified files under checkpoints/service/)
LAST_OWN_INLINE_FORMAT = "8dbaee8"


# the one line of a Ctrl-C during a command's start-up, before training began (exit 130)
STARTUP_STOP = "stopped by SIGINT during start-up, before training began: nothing was trained, nothing to resume"


class RunRequestError(ValueError):
    """A combination of flags no runner can honour (the message names the flag and its value)."""


class ResumeMismatch(RunRequestError):
    """The run to resume holds checkpoints of a format this version does not read (the message says what does)."""


@dataclass(frozen=True)
class RunRequest:
    """What one training command asks for, whichever entry point parsed it.

    runner: which runner trains; config_file: TOML experiment file (None: the built-in defaults, MADDPG on sparse
    navigation; ignored on resume);
    overrides: "section.key=value" strings, in order; resume_dir: the run to continue (None: a new run in run.dir);
    overwrite: start over in a run.dir that holds a run; more_episodes: on resume, train this many episodes past
    those the run has done (run.episodes becomes their sum; a default λ schedule keeps its stride); quiet: no
    progress lines; no_eval: no evaluation, GIF or learning curve at the end. Service only: address (Ray cluster to
    join, None: embedded Ray), num_cpus (CPUs of the embedded Ray, None: all), ray_metrics_port (port of the
    embedded Ray's own metrics). metrics_port / metrics_host become `service.metrics_port` /
    `service.metrics_host` overrides (`config_overrides`).
    """

    runner: Runner
    config_file: str | None = None
    overrides: tuple[str, ...] = ()
    resume_dir: str | None = None
    overwrite: bool = False
    more_episodes: int = 0
    quiet: bool = False
    no_eval: bool = False
    address: str | None = None
    num_cpus: int | None = None
    metrics_port: int | None = None
    metrics_host: str | None = None
    ray_metrics_port: int | None = None

    def __post_init__(self) -> None:
        if self.runner not in RUNNERS:
            raise RunRequestError(f"--runner must be one of {', '.join(RUNNERS)}, got {self.runner!r}")
        if self.more_episodes < 0:
            raise RunRequestError(f"--more-episodes must be >= 0, got {self.more_episodes}")
        if self.num_cpus is not None and (isinstance(self.num_cpus, bool) or self.num_cpus < 1):
            raise RunRequestError(f"--num-cpus must be a positive integer (CPUs of the embedded Ray), got "
                                  f"{self.num_cpus}")
        if self.more_episodes and not self.resume_dir:
            raise RunRequestError(f"--more-episodes {self.more_episodes} trains a run further: give the run "
                                  "(python -m cmcl resume RUN_DIR --more-episodes N)")
        if self.runner == "inline":
            for field, flag in SERVICE_ONLY_FLAGS.items():
                if getattr(self, field) is not None:
                    raise RunRequestError(f"{flag} {getattr(self, field)} is a flag of the service runner; the inline "
                                          "runner trains in this process, without Ray or a metrics endpoint (use "
                                          "--runner service)")

    def config_overrides(self) -> tuple[str, ...]:
        """The `--set` overrides followed by those the metrics flags stand for."""
        extra = list(self.overrides)
        if self.metrics_port is not None:
            extra.append(f"service.metrics_port={self.metrics_port}")
        if self.metrics_host is not None:
            extra.append(f'service.metrics_host="{self.metrics_host}"')
        return tuple(extra)


def no_update_line(config: Config, summary: dict[str, Any]) -> str | None:
    """The one line of a run that ended without a learner update (its `summary` counts 0 updates), naming the
    warm-up and the env steps taken; None when it trained."""
    if summary.get("updates", 1) != 0:
        return None
    m = config.maddpg
    return (f"note: no learner update in this run: the first waits for maddpg.warmup = {m.warmup} transitions in the "
            f"replay, then one every maddpg.update_every = {m.update_every} env steps, and the run took "
            f"{summary.get('env_steps', 0)} env steps ({summary.get('episodes', 0)} episodes); the policy is the "
            "untrained one. Raise run.episodes or lower maddpg.warmup")


def open_run(request: RunRequest) -> tuple[Config, RunDirectory, RunLock]:
    """The config (file, or the run's own config.toml on resume, with `config_overrides`), the run directory (new, or
    the one resumed) and its lock, taken before anything in the directory changes: a run in use is refused, naming
    its holder, and left untouched; so is the other runner's run, and a key only the other runner honours
    (cmcl.config.runners.check_runner_keys). Raises ConfigError (also a run.dir that cannot be made a folder),
    FileExistsError (a run.dir holding a run, without `overwrite`), FileNotFoundError (no run to resume),
    RunDirectoryInUse, ResumeMismatch, CheckpointError (a resumed run holds checkpoint files that cannot be verified),
    MetricsError (its metrics.jsonl has a corrupt line before its last)."""
    overrides = request.config_overrides()
    if request.resume_dir:
        run_dir = RunDirectory.open(request.resume_dir)
        lock = RunLock.acquire(run_dir.path, holder_command())
        try:
            if "inline" in run_dir.runners():
                raise ResumeMismatch(f"{request.resume_dir} holds checkpoints of the inline runner's own format "
                                     f"(checkpoints/ckpt_*.pt), which this version no longer reads: resume it with "
                                     f"the code of commit {LAST_OWN_INLINE_FORMAT} (`git checkout "
                                     f"{LAST_OWN_INLINE_FORMAT}`), or start a new run")
            run_dir.check_no_unverifiable_checkpoint()
            config = resumed_config(run_dir, overrides, request)
            ready = checked(config, request, port_given=port_given_by(request, config))
            try:
                record_resume_settings(run_dir, config, request)
            except RunWriteError as err:  # a full disk: the one line of every write failure, before any training
                kept = resume_point(run_dir)
                raise ConfigError(write_failure_line(err, run_dir.path, kept)) from None
            return ready, run_dir, lock
        except BaseException:
            lock.release()
            raise
    file_data = load_data(request.config_file)
    data = apply_overrides(file_data, overrides)
    config = config_from_file(data, file_data, request.config_file)
    check_runner_keys(config, request.runner, file_data, overrides)  # keys only the other runner honours
    check_world_keys(config, file_data, overrides)  # the built-in worlds' keys, with env.factory
    config = checked(config, request, teams_given="teams" in data,  # the env built once (AEC, ...)
                     port_given=port_given(config, file_data, overrides),
                     length_given=key_given(file_data, overrides, "env", "episode_length"))
    from cmcl.run.carried_replay import check_carry_source  # numpy only: no torch, no Ray

    check_carry_source(config)  # before the warm start's shape check: it names the setting (env.agent_tags, ...)
    check_warm_start(config)
    try:
        lock = RunLock.acquire(config.run.dir, holder_command())
    except OSError as err:  # a path that cannot be a folder (a file, under /proc, no permission): name the key
        why = {errno.EEXIST: "it is a file", errno.ENOTDIR: "a folder on its path is a file"}.get(
            err.errno, err.strerror or str(err))
        raise ConfigError(f"run.dir = {str(config.run.dir)!r} cannot hold a run: {why}") from None
    try:
        return config, RunDirectory.create(config.run.dir, config, overwrite=request.overwrite), lock
    except ForeignFolderError:
        lock.discard()  # the user's folder is left as it was, without our lock file
        raise
    except BaseException:
        lock.release()
        raise


def config_from_file(data: Mapping[str, Any], file_data: Mapping[str, Any], config_file: str | None) -> Config:
    """`config_from_dict(data)` (the file's tables `file_data` with the overrides); a ConfigError that the file's
    tables alone raise too names the file ('... (in configs/x.toml)'), one the overrides brought does not."""
    try:
        return config_from_dict(data)
    except ConfigError as err:
        if config_file is None:
            raise
        try:
            config_from_dict(file_data)
        except ConfigError as own:
            if str(own) == str(err):
                raise ConfigError(f"{err} (in {config_file})") from None
        raise


def checked(config: Config, request: RunRequest, teams_given: bool = True, port_given: bool = True,
            length_given: bool = True) -> Config:
    """`config` after `cmcl.run.preflight.preflight`: the environment built and stepped once, the teams matched (the
    env's own, with default settings, when `teams_given` is false and they differ from the default team), the memory of
    the worlds (of every rollout worker on the service) and the replay checked, unless the run joins a cluster
    (--address: its nodes' memory is not this machine's); on the service, service.metrics_port free: a port the user
    gave (`port_given`) is refused when in use, the default one (9100, also node_exporter's) is then replaced by a
    free one, said on stderr; an env.factory run whose env.episode_length is set nowhere (`length_given` false)
    takes the env's own episode length (`cmcl.run.preflight.with_episode_length`). Raises ConfigError."""
    from cmcl.run.preflight import metrics_port_checked, preflight  # numpy and the env package: no torch, no Ray

    service = request.runner == "service"
    if service:  # the launcher serves it once Ray has started: a port in use is named before
        config = metrics_port_checked(config, port_given)
    workers = config.service.rollout_workers if service else 1
    return preflight(config, teams_given=teams_given, length_given=length_given, worker_processes=workers,
                     check_memory=not request.address)


def port_given(config: Config, file_data: Mapping[str, Any], overrides: tuple[str, ...]) -> bool:
    """Whether the user chose service.metrics_port: in the config file, by --set (or --metrics-port), or as a value
    other than the default (a resumed run's config.toml holds every key)."""
    return (config.service.metrics_port != Config().service.metrics_port
            or key_given(file_data, overrides, "service", "metrics_port"))


def key_given(file_data: Mapping[str, Any], overrides: tuple[str, ...], section: str, key: str) -> bool:
    """Whether `section.key` is set in the config file's tables (`file_data`) or by an override (--set)."""
    table = file_data.get(section, {})
    return ((isinstance(table, Mapping) and key in table)
            or any(parse_override(text)[0] == [section, key] for text in overrides))


def port_given_by(request: RunRequest, config: Config) -> bool:
    """`port_given` of `request`: its config file's tables (a new run's) and its overrides."""
    file_data = load_data(request.config_file) if request.config_file and not request.resume_dir else {}
    return port_given(config, file_data, request.config_overrides())


def resumed_config(run_dir: RunDirectory, overrides: tuple[str, ...], request: RunRequest) -> Config:
    """The resumed run's config: its config.toml with `overrides`, and with `request.more_episodes` > 0
    run.episodes set to the episodes done (its last episode row's) plus those, the λ stride pinned first when it was
    derived from the old budget (curriculum.stride = 0), so that λ goes on along the schedule it had (a multiplicative
    schedule, whose growth has no setting, is refused: ConfigError). A run whose episodes are all done, resumed
    without more, is said so on stderr (it then only evaluates). Only `overrides` are checked against the runner
    (cmcl.config.runners: the stored config was checked when the run started), and against the shapes the run's
    checkpoints hold (cmcl.run.resume_shapes: ConfigError naming them)."""
    config = run_dir.config(overrides)
    check_runner_keys(config, request.runner, overrides=overrides)
    check_world_keys(config, overrides=overrides)
    if overrides:  # one that changes what the checkpoints hold is refused here, naming it (cmcl.run.resume_shapes)
        from cmcl.run.resume_shapes import check_resume_shapes  # torch: only when a resume sets something

        check_resume_shapes(run_dir.config(), config, overrides)
    done = max((int(row["episodes"]) for row in run_dir.rows("episode")), default=0)
    if request.more_episodes:
        if config.curriculum.kind != "linear":  # its growth per step is derived from run.episodes, with no setting
            raise ConfigError(f"--more-episodes {request.more_episodes}: curriculum.kind = "
                              f"{config.curriculum.kind!r} derives λ's growth from run.episodes, so λ would jump; "
                              "only the linear kind keeps its schedule")
        stride = config.curriculum.stride or config.curriculum_stride()
        total = done + request.more_episodes
        config = run_dir.config((*overrides, f"curriculum.stride={stride!r}", f"run.episodes={total}"))
        if not request.quiet:
            reads_lambda = uses_lambda(team.algorithm for team in config.teams.values())
            print(f"run.episodes: {total} ({request.more_episodes} more than the {done} done)"
                  + (f"; λ stride {stride:.4g} per env step" if reads_lambda else ""))
    elif done >= config.run.episodes:
        print(f"note: {run_dir.path} has done all its run.episodes = {config.run.episodes}: nothing to train. To "
              f"train further: {resume_command(run_dir.path)} --more-episodes N", file=sys.stderr)
    return config


def flat_settings(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested config mapping (`Config.to_dict`) as {"section.key": value}, every table flattened
    ("teams.agent.priority.alpha", "env.factory_kwargs.max_cycles")."""
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, Mapping):
            flat.update(flat_settings(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def record_resume_settings(run_dir: RunDirectory, config: Config, request: RunRequest) -> None:
    """Write a resume's settings to the run's config.toml, which resume, status, evaluate and summary.json's
    provenance read, so that a later plain resume keeps them; one line per changed key ("resume sets
    maddpg.actor_lr: 0.001 -> 0.5"). The metrics flags (--metrics-port, --metrics-host) are this command's only:
    the stored values stay unless a --set names them. Nothing is written when nothing changed."""
    stored = run_dir.config()
    flagged = {("service", "metrics_port"): "metrics_port", ("service", "metrics_host"): "metrics_host"}
    service = config.service
    for (section, key), field in flagged.items():
        if not any(parse_override(text)[0] == [section, key] for text in request.overrides):
            service = dataclasses.replace(service, **{field: getattr(stored.service, field)})
    config = dataclasses.replace(config, service=service)
    old, new = flat_settings(stored.to_dict()), flat_settings(config.to_dict())
    changed = [key for key in new if old.get(key) != new[key]]
    if not changed:
        return
    for key in changed:
        print(f"resume sets {key}: {old.get(key)!r} -> {new[key]!r} (recorded in {run_dir.config_path.name})")
    atomic_write_bytes(run_dir.config_path, dump_toml(config).encode())


def check_warm_start(config: Config) -> None:
    """Refuse a run.init_from whose policy this config cannot load (no run, no policy, other network shapes) with a
    ConfigError naming the field and the value, before the new run's directory exists."""
    if not config.run.init_from:
        return
    from cmcl.run.warm_start import warm_start_from_config
    from cmcl.system import build_maddpg, layout_of

    probe = build_maddpg(config, layout_of(config), seed=0)
    try:
        warm_start_from_config(config.run.init_from, probe)
    except ValueError as err:
        raise ConfigError(str(err)) from err


def train_in_run(request: RunRequest, train: Callable[[Config, RunDirectory, RunLock], int]) -> int:
    """Open the run (`open_run`) and call `train(config, run_dir, lock)` while holding its lock; returns its exit
    code, or 2 after printing the error when the run cannot be opened (nothing in the directory changed then) or
    when the user's environment (`env.factory`) cannot be used (EnvFactoryError: an AEC env, an unsupported space,
    an observation that does not fit its space, ...) or a file of the run cannot be written (RunWriteError: a full
    disk; the line names the file and what a resume starts from, `resume_point`). A new run that fails (an error
    exit or an exception, not a stop by signal) before its first episode is removed again, its directory too when
    this command made it (`RunDirectory.discard_failed_start`)."""
    try:
        config, run_dir, lock = open_run(request)
    except KeyboardInterrupt:  # a Ctrl-C while the run is checked (env, memory): nothing was made
        print(STARTUP_STOP, file=sys.stderr)
        return 130
    except (CheckpointError, ConfigError, EnvFactoryError, FileExistsError, FileNotFoundError, MetricsError,
            RunDirectoryInUse, RunRequestError, RunWriteError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    code = 1
    with lock:
        try:
            code = train(config, run_dir, lock)
            if code == 0 and request.no_eval:  # with an evaluation, cmcl.run.report.report_trained says it first
                untrained = no_update_line(config, run_dir.summary())
                if untrained:
                    print(untrained)
            return code
        except EnvFactoryError as err:  # the user's environment, built or stepped: one line, no traceback
            print(f"error: {err}", file=sys.stderr)
            code = 2
            return code
        except KeyboardInterrupt:  # a Ctrl-C before the runner's own stop handler (e.g. during Ray's start)
            print(STARTUP_STOP, file=sys.stderr)
            code = 130
            return code
        except RunWriteError as err:  # a full disk, in either runner: what was written stays as it was
            kept = resume_point(run_dir)
            record_write_failure(run_dir, request.runner, err, kept)
            print(f"error: {write_failure_line(err, run_dir.path, kept)}", file=sys.stderr)
            code = 2
            return code
        finally:  # a new run that failed before its first episode leaves nothing that blocks the retry
            if (code not in (0, 143) and not request.resume_dir and run_dir.never_trained()
                    and (code != 130 or not run_dir.summary())):
                run_dir.discard_failed_start()
                lock.discard()


def record_write_failure(run_dir: RunDirectory, runner: Runner, err: RunWriteError, kept: str | None) -> None:
    """Record in summary.json that the run stopped in order because `err`'s file could not be written (ended
    "write_failure", the error, what a resume starts from: `kept`, None for nothing), with the episodes and training
    seconds of its last metrics row, so that `status` tells this stop from a crash and a run with nothing to resume
    may start again (`RunDirectory.stopped_before_a_checkpoint`). On a disk with no room left at all this write fails
    too, and the run reads as cut off."""
    last: dict[str, Any] = {}
    try:
        for row in run_dir.rows():
            if row.get("kind") in ("episode", "progress"):
                last = row
        run_dir.write_summary({"runner": runner, "ended": "write_failure", "error": str(err), "resume_from": kept,
                               "episodes": int(last.get("episodes", 0)),
                               "elapsed_s": float(last.get("elapsed_s", 0.0))})
    except (OSError, MetricsError):
        pass


def resume_point(run_dir: RunDirectory) -> str | None:
    """What a resume of `run_dir` starts from, said when a file of the run could not be written: its last checkpoint;
    a run without a policy checkpoint yet resumes from its replay alone (either runner: services.launch.resume_notice);
    None when there is nothing to resume from."""
    if run_dir.runners():
        return "its last checkpoint"
    return "its replay (no policy checkpoint yet)" if any(run_dir.service_replay_dir.glob("*")) else None


def add_run_flags(parser: argparse.ArgumentParser, *, new_run: bool = True) -> None:
    """Add the flags of a training run to `parser`. new_run=False leaves out --config and --overwrite (a resume
    reads the run's own config.toml and never starts over)."""
    if new_run:
        parser.add_argument("--config",
                            help="TOML experiment file (default: the built-in defaults, MADDPG on sparse navigation)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override one config value (repeatable)")
    if new_run:
        parser.add_argument("--overwrite", action="store_true", help="start over in a run.dir that holds a run")
    else:
        add_more_episodes_flag(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.add_argument("--no-eval", action="store_true",
                        help="skip the held-out evaluation, the GIF and the learning curve at the end")
    service = parser.add_argument_group("service runner only")
    service.add_argument("--metrics-port", type=int, default=None,
                         help="Prometheus port of the service (default service.metrics_port; 0 picks a free one)")
    service.add_argument("--metrics-host", default=None, help="bind address of the metrics (default 127.0.0.1)")
    service.add_argument("--address", default=None,
                         help="Ray cluster to join ('auto' after `ray start --head`); default: embedded Ray")
    service.add_argument("--num-cpus", type=int, default=None,
                         help="CPUs of the embedded Ray, a positive integer (default: all)")
    service.add_argument("--ray-metrics-port", type=int, default=None,
                         help="embedded Ray only: port of Ray's own Prometheus metrics (default: Ray picks one)")


def alias_parser(prog: str, description: str) -> argparse.ArgumentParser:
    """The parser of a runner's own command (`python -m services.launch`): the run flags and
    `--resume DIR`, the runner fixed by the command."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    add_run_flags(parser)
    parser.add_argument("--resume", metavar="DIR", help="continue the run in DIR from its newest checkpoint")
    add_more_episodes_flag(parser)
    return parser


def add_more_episodes_flag(parser: argparse.ArgumentParser) -> None:
    """`--more-episodes N` of a resume: train N episodes past those the run has done."""
    parser.add_argument("--more-episodes", type=int, default=0, metavar="N",
                        help="resume only: train N episodes past those the run has done (run.episodes grows; "
                             "the λ schedule keeps its stride)")


def request_from(args: argparse.Namespace, runner: str, resume_dir: str | None = None) -> RunRequest:
    """The `RunRequest` of a parsed namespace (from `add_run_flags`, plus `--resume` on the aliases)."""
    return RunRequest(runner=runner, config_file=getattr(args, "config", None), overrides=tuple(args.overrides),
                      resume_dir=resume_dir or getattr(args, "resume", None),
                      overwrite=getattr(args, "overwrite", False),
                      more_episodes=getattr(args, "more_episodes", 0), quiet=args.quiet, no_eval=args.no_eval,
                      address=args.address, num_cpus=args.num_cpus, metrics_port=args.metrics_port,
                      metrics_host=args.metrics_host, ray_metrics_port=args.ray_metrics_port)


def run_alias(args: argparse.Namespace, runner: str, run: Callable[[RunRequest], int]) -> int:
    """A runner's own command: `run(request_from(args, runner))`, or exit code 2 after a one-line error when the
    flags make no valid request (e.g. --num-cpus 0)."""
    try:
        request = request_from(args, runner)
    except RunRequestError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return run(request)


def add_evaluate_flags(parser: argparse.ArgumentParser) -> None:
    """Add the flags of `evaluate RUN_DIR` to `parser`."""
    parser.add_argument("run_dir", metavar="RUN_DIR", help="a run directory written by either runner")
    parser.add_argument("--checkpoint", help="checkpoint file (default: the run's newest verified policy, "
                                             "whichever runner wrote it)")
    parser.add_argument("--episodes", type=int, default=100, help="held-out episodes (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the held-out worlds (offset from training's)")
    parser.add_argument("--random", action="store_true", help="evaluate a uniform random policy instead")
    parser.add_argument("--gif", help="GIF path (default: <run_dir>/eval.gif)")
    parser.add_argument("--no-gif", action="store_true", help="no GIF")
