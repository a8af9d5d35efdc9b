"""The service's command line: embedded Ray by default, or join a cluster with --address auto.

`python -m cmcl train` (the default runner) and `python -m cmcl resume DIR` (a run the service wrote) call
`run_launch`; `python -m services.launch` is their alias and the cluster command of the deploy files, with the
same flags (cmcl/run/flags.py) and `--resume DIR`:

    python -m services.launch [--config F] [--set section.key=value ...] [--address auto]
                              [--metrics-port P] [--metrics-host H] [--resume DIR] [--num-cpus N]

Where it sits: the entry point. It validates the config, starts (or joins) Ray, opens the Prometheus endpoint,
creates every role (services.runtime.placement.create_roles) and runs the supervisor loop until run.episodes episodes
(or run.max_seconds), then checkpoints, writes the learning curve and shuts down cleanly.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from cmcl.config import Config
from cmcl.envs.factory import EnvFactoryError
from cmcl.io.durable import ReplayStore, StoreError
from cmcl.io.resume_hint import resume_command
from cmcl.io.write_failure import RunWriteError
from cmcl.progress.rows import TrainingDiverged
from cmcl.run.flags import RunRequest, alias_parser, port_given_by, run_alias, train_in_run
from cmcl.run.report import done_line, report_trained
from cmcl.run.rundir import RunDirectory
from cmcl.run.runlock import RunLock
from cmcl.run.stopping import STOP_SIGNALS, StopSignals, exit_without_teardown
from services.runtime.loopback import loopback_only


def build_parser() -> argparse.ArgumentParser:
    """The alias's flags: those of every training command (cmcl/run/flags.py) and `--resume DIR`."""
    return alias_parser("python -m services.launch", __doc__.split("\n")[0])


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


JOIN_TIMEOUT_S = 5.0  # per connection attempt of the probe below (Ray's GCS client makes up to three)
UNREACHABLE = ("Timed out", "Failed to connect", "UNAVAILABLE", "status: 404")  # the probe's errors that mean "no GCS"


def check_cluster_reachable(address: str, timeout_s: float = JOIN_TIMEOUT_S) -> None:
    """Raise ConnectionError (one line, naming --address) when no Ray cluster answers at `address` within about
    3 × `timeout_s`: Ray's own join retries for minutes with only warnings. "auto" is the cluster `ray start`
    recorded on this machine (or RAY_ADDRESS). The probe is a standalone GCS client, its C++ warnings kept off the
    terminal; any answer other than "nothing there" (e.g. an auth refusal) is left to ray.init to report. A Ray
    Client address (ray://) is not probed."""
    from ray._private.services import canonicalize_bootstrap_address  # Ray's own reading of "auto" and host:port
    from ray._raylet import InnerGcsClient

    hint = "start one with `ray start --head`, or omit --address for an embedded Ray"
    if address.startswith("ray://"):
        return
    try:
        target = canonicalize_bootstrap_address(address)
    except (ConnectionError, ValueError, OSError) as err:
        raise ConnectionError(f"cannot join the Ray cluster at --address {address}: {str(err).rstrip('.')}; "
                              f"{hint}") from None
    if target is None:
        raise ConnectionError(f"cannot join the Ray cluster at --address {address}: no cluster found; {hint}")
    started = time.monotonic()
    try:
        with stderr_to(Path(os.devnull)):
            InnerGcsClient.standalone(target, None, int(timeout_s * 1000))
    except Exception as err:  # noqa: BLE001 - Ray's RpcError has no public class
        if any(text in str(err) for text in UNREACHABLE):
            raise ConnectionError(f"cannot join the Ray cluster at --address {address}: no Ray cluster answered at "
                                  f"{target} within {time.monotonic() - started:.0f} s ({str(err).rstrip('.')}); "
                                  f"{hint}") from None


def start_ray(address: str | None, num_cpus: int | None, metrics_export_port: int | None = None) -> None:
    """Join `address` (the cluster's own network settings), or start an embedded Ray sized to this machine (no
    dashboard), every server of it listening on 127.0.0.1 only (services/runtime/loopback.py).

    The embedded Ray's processes are started with SIGINT and SIGTERM blocked, a mask they inherit: a Ctrl-C in the
    terminal reaches the whole foreground process group, and it must stop the run through the launcher (drain,
    checkpoint), not kill Ray's processes under it. A signal that arrives meanwhile waits, then reaches the
    launcher's handler once the caller unblocks it (`unblock_stop_signals`)."""
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
    loopback_only()  # every server of the embedded Ray on 127.0.0.1 (services/runtime/loopback.py)
    receiver = sigint_receiver()  # a Ctrl-C meanwhile interrupts ray.init (KeyboardInterrupt), within a second
    signal.pthread_sigmask(signal.SIG_BLOCK, set(STOP_SIGNALS))
    try:
        ray.init(address="local", num_cpus=os.cpu_count() if num_cpus is None else num_cpus, include_dashboard=False,
                 log_to_driver=False, _metrics_export_port=metrics_export_port)
    except Exception as err:  # noqa: BLE001 - Ray raises bare Exception (e.g. "timed out during startup")
        raise ConnectionError(f"the embedded Ray did not start: {str(err).strip().splitlines()[0]} (its logs: "
                              "/tmp/ray/session_latest/logs)") from None
    finally:
        receiver.set()


def sigint_receiver() -> threading.Event:
    """Start a daemon thread that keeps SIGINT unblocked (SIGTERM blocked) and return the event that ends it. Made
    before `start_ray` blocks both signals in the main thread, it is where the kernel delivers a Ctrl-C meanwhile;
    Python then runs the SIGINT handler in the main thread, inside ray.init (KeyboardInterrupt: the command stops at
    once, nothing to resume, and the reaper ends what Ray had started), while Ray's processes, which the main thread
    starts, keep both signals blocked."""
    ready, done = threading.Event(), threading.Event()

    def receive() -> None:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})  # SIGTERM waits for the launcher, as before
        ready.set()
        done.wait()

    threading.Thread(target=receive, name="sigint-receiver", daemon=True).start()
    ready.wait()
    return done


def stop_ray() -> None:
    """Disconnect this driver from Ray; the processes of an embedded Ray are then SIGKILLed at once.

    `ray.shutdown()` sends each process it started SIGTERM and waits up to 1 s before a SIGKILL, one process after the
    other; the embedded Ray's processes have SIGTERM blocked (`start_ray`), so that was ~1 s for each of them (5 s on
    every stop) spent waiting for nothing. By now every role has checkpointed, and the driver's disconnect has already
    had the raylet end the actors' workers; a joined cluster (`--address`) is only disconnected from, as before."""
    import ray
    from ray._private import worker  # Ray offers no public switch for the SIGTERM grace of its shutdown

    node = worker._global_node
    worker._global_node = None  # so that ray.shutdown() only disconnects; the processes are ended below
    try:
        ray.shutdown()
    finally:
        if node is not None:
            if node.is_head():
                node.destroy_external_storage()  # what ray.shutdown() does before ending the processes
            node.kill_all_processes(check_alive=False, allow_graceful=False)


def unblock_stop_signals() -> None:
    """Let SIGINT / SIGTERM reach this process again (after `start_ray`; any signal held meanwhile arrives now)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, set(STOP_SIGNALS))


@contextlib.contextmanager
def stderr_to(path: Path) -> Iterator[None]:
    """Send this process's file descriptor 2 (where Ray's C++ core and Python loggers write) to `path` meanwhile:
    what Ray prints on its way out goes to the run directory, not to the user's terminal."""
    sys.stderr.flush()
    saved = os.dup(2)
    with path.open("ab") as sink:
        os.dup2(sink.fileno(), 2)
    try:
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)


def run_service(config: Config, run_dir: RunDirectory, *, resume: bool = False, progress: Any = print,
                stop: Callable[[], bool] | None = None,
                started: Callable[[Any, Any], None] | None = None, port_fallback: bool = False,
                in_process: bool = False) -> dict[str, Any]:
    """Run the roles of `config` under the supervisor; returns its final summary. On the Ray already initialised
    (each role an actor, the metrics served on service.metrics_port), or with `in_process` the same roles as plain
    objects in this process (`--runner inline`: services.runtime.calls.InProcessCalls; no Ray, no metrics endpoint).
    `stop` is polled between rounds of work (see `Supervisor`); `started(supervisor, roles)`, if given, is called once
    both exist, before the supervisor runs (a bench watching the run: bench/service_breakdown.py). `port_fallback`: the
    user did not choose service.metrics_port (cmcl.run.flags.port_given), so a port taken since the check before Ray
    (another run starting beside this one) is replaced by a free one, said in a note, rather than refused."""
    from services.observability.metrics import ServiceMetrics
    from services.runtime.calls import InProcessCalls, RayCalls
    from services.runtime.placement import create_roles
    from services.runtime.supervisor import Supervisor

    metrics = ServiceMetrics(seed=config.run.seed)
    port = None if in_process else serve_metrics(metrics, config, port_fallback)
    try:
        if progress is not None:
            where = "" if port is None else f"metrics: http://{config.service.metrics_host}:{port}/metrics   "
            progress(f"{where}run directory: {run_dir.path}")
        roles = create_roles(config, run_dir, in_process=in_process)
        supervisor = Supervisor(config, run_dir, roles, metrics, progress=progress, stop=stop,
                                calls=InProcessCalls() if in_process else RayCalls())
        if resume:
            supervisor.restore_counters()
        if started is not None:
            started(supervisor, roles)
        summary = supervisor.run()
        if port is not None:
            summary["metrics_port"] = port
        summary["metrics_text"] = metrics.text()
        return summary
    finally:
        metrics.close()


def train_in_process(config: Config, run_dir: RunDirectory, *, resume: bool = False, progress: Any = None,
                     stop: Callable[[], bool] | None = None) -> tuple[dict[str, Any], Any]:
    """One run of the inline runner from Python (tests, benches, the fingerprint): the roles of `config` trained in
    this process (`run_service(in_process=True)`). Returns (the supervisor's final summary, the roles: e.g.
    `roles.learner.maddpg`, `roles.replay.replay`)."""
    roles: list[Any] = []
    summary = run_service(config, run_dir, resume=resume, progress=progress, stop=stop, in_process=True,
                          started=lambda _supervisor, r: roles.append(r))
    return summary, roles[0]


def serve_metrics(metrics: Any, config: Config, port_fallback: bool) -> int:
    """Serve `metrics` on service.metrics_host:metrics_port (a free port when it was taken since the check before
    Ray and the user did not choose it: `port_fallback`, said in a note); returns the port."""
    host, port = config.service.metrics_host, config.service.metrics_port
    try:
        return metrics.serve(port, host)
    except OSError as err:  # taken since the check before Ray (cmcl.run.preflight.metrics_port_checked)
        if not port_fallback:
            raise OSError(f"service.metrics_port = {port} cannot be bound on {host} ({err.strerror or err}): pass "
                          "--metrics-port 0 for a free port, or another port") from None
        print(f"note: service.metrics_port = {port} was taken on {host} since the check before Ray; the metrics are "
              "served on a free port instead (the `metrics:` line names it; --metrics-port chooses one)",
              file=sys.stderr)
        return metrics.serve(0, host)


def resume_notice(run_dir: RunDirectory) -> str:
    """What a resume starts from: the newest verified policy, or that the learner starts afresh."""
    policy = run_dir.newest_policy()
    if policy is None:
        return f"resuming {run_dir.path}: no policy checkpoint yet, the learner starts afresh (the replay is kept)"
    version = policy.state.get("version")
    return (f"resuming {run_dir.path} from {policy.path.relative_to(run_dir.path)}"
            + (f" (policy version {int(version)})" if version is not None else ""))


def main(argv: list[str] | None = None) -> int:
    """`python -m services.launch`: the alias of `python -m cmcl train|resume --runner service`."""
    return run_alias(parse_args(argv), "service", run_launch)


def run_launch(request: RunRequest) -> int:
    """Train, or resume, one service run. Exit codes: 0 done, 2 bad config / arguments / cluster / resources / run
    directory in use, 130 / 143 stopped by SIGINT / SIGTERM (every role checkpointed first)."""
    if request.address:  # before the run directory is made and before Ray: an absent cluster is one line, at once
        try:
            check_cluster_reachable(request.address)
        except ConnectionError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
    return train_in_run(request, lambda config, run_dir, lock: _launch(request, config, run_dir, lock))


def _launch(request: RunRequest, config: Config, run_dir: RunDirectory, lock: RunLock) -> int:
    """Train until done or stopped, then report; the lock is held. The service starts (or joins) Ray and shuts it
    down quietly at the end; the inline runner (`request.runner == "inline"`) runs the same roles in this process."""
    from services.runtime.placement import InfeasibleResources

    in_process = request.runner == "inline"
    if request.resume_dir:
        print(resume_notice(run_dir))
        damage = ReplayStore(run_dir.service_replay_dir).recover_log()
        if damage is not None:
            print(f"replay log of {run_dir.path}: {damage}", file=sys.stderr)
    elif config.run.init_from:  # the learner loads it (services/roles/learner.py); checked by open_run
        from cmcl.run.warm_start import warm_start_source  # torch: imported only when needed

        print(f"actors and critics initialised from {warm_start_source(config.run.init_from).path}")
        if config.run.carry_replay:  # the replay server reads them when it starts (services/roles/replay_server.py)
            print(f"replay: starts with the rows of {config.run.init_from}")
    stop = StopSignals(notice=print)
    try:
        if in_process:
            stop.install()
        else:
            started = _start_embedded_or_join(request, lock, stop)
            if started is not None:
                return started
        try:
            summary = run_service(config, run_dir, resume=bool(request.resume_dir),
                                  progress=None if request.quiet else print, stop=lambda: stop.requested,
                                  port_fallback=not port_given_by(request, config), in_process=in_process)
        except RunWriteError:  # a full disk (a role's file, the metrics, the counters): cmcl.run.flags.train_in_run
            raise  # names the file and what a resume starts from
        except (InfeasibleResources, OSError, StoreError) as err:  # StoreError: a replay snapshot that fails its
            print(f"error: {err}", file=sys.stderr)  # checks (cmcl.io.durable), kept as it is
            return 2
        except TrainingDiverged as err:  # every role's last checkpoint before it stays the run's newest
            run_dir.write_summary({"runner": request.runner, "ended": "diverged"})
            print(f"error: {err}", file=sys.stderr)
            return 2
        except EnvFactoryError as err:  # the user's environment raised or misfit: every role checkpointed first
            run_dir.write_summary({"runner": request.runner, "ended": "env_error"})
            print(f"error: {err}; the run is kept (every role checkpointed); resume with: "
                  f"{resume_command(run_dir.path)}", file=sys.stderr)
            return 2
        finally:
            stop.training_over()
            if not in_process:
                with stderr_to(run_dir.path / "ray_shutdown.log"):
                    stop_ray()
        return _report(request, config, run_dir, summary, stop)
    finally:
        stop.restore()


def _start_embedded_or_join(request: RunRequest, lock: RunLock, stop: StopSignals) -> int | None:
    """Start the embedded Ray (with the reaper: no process of it outlives this one, SIGKILL included) or join
    --address; then the stop signals. Returns 2 after a one-line error when Ray cannot be had, else None."""
    import ray

    from services.runtime.reaper import start_reaper

    if not request.address and not ray.is_initialized():
        start_reaper(keep_fds=(lock.fd,))
    try:
        start_ray(request.address, request.num_cpus, request.ray_metrics_port)
    except ConnectionError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    finally:
        # after ray.init, whose core worker installs a C-level SIGTERM handler (a stack dump and abort) over
        # any earlier one; then a signal held during Ray's start arrives and only sets `stop.requested`
        stop.install()
        unblock_stop_signals()
    return None


def _report(request: RunRequest, config: Config, run_dir: RunDirectory, summary: dict[str, Any],
            stop: StopSignals) -> int:
    """The end of a run: summary.json, the `done` line, then the resume hint (stopped) or the evaluation."""
    ended = stop.name or ("solved" if summary.get("solved") else "plateau" if summary.get("plateau") else "budget")
    summary = {**{k: v for k, v in summary.items() if k != "metrics_text"}, "ended": ended, "runner": request.runner}
    run_dir.write_summary(summary)
    print(done_line(summary, config.run.stop_coverage))
    if stop.requested:
        print(f"stopped by {stop.name}; every role is checkpointed. Resume with: "
              f"{resume_command(run_dir.path)}")
        return stop.exit_code
    if not request.no_eval:
        report_trained(config, run_dir)
    return 0


if __name__ == "__main__":
    exit_without_teardown(main())  # the exit status of sys.exit, without ~1-2 s of teardown
