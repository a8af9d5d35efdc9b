"""The service's metrics port (cmcl.run.preflight.metrics_port_checked, cmcl.run.flags.port_given): a port the user
chose is refused when in use; the default one (9100, also Prometheus node_exporter's default) in use is replaced by a
free port with a note, so that `make run` does not fail on a machine that runs node_exporter (before, 2026-12-06: it
ended in "service.metrics_port = 9100 is in use ... pass --metrics-port 0", which `make run` cannot pass without
RUN_ARGS)."""

from __future__ import annotations

import socket
from dataclasses import replace

import pytest

from cmcl.config import Config, ConfigError
from cmcl.run.flags import port_given
from cmcl.run.preflight import metrics_port_checked
from tests.tiny import make_tiny_config


@pytest.fixture
def busy_port():
    """A port of 127.0.0.1 held by a listening socket for the test."""
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        yield held.getsockname()[1]


def with_port(port: int) -> Config:
    config = make_tiny_config("maddpg")
    return replace(config, service=replace(config.service, metrics_port=port, metrics_host="127.0.0.1"))


def test_a_default_port_in_use_becomes_a_free_one_with_a_note(busy_port, capsys):
    checked = metrics_port_checked(with_port(busy_port), port_given=False)
    assert checked.service.metrics_port == 0
    assert capsys.readouterr().err == (f"note: service.metrics_port = {busy_port} is in use on 127.0.0.1; the metrics "
                                       "are served on a free port instead (the `metrics:` line names it; "
                                       "--metrics-port chooses one)\n")


def test_a_chosen_port_in_use_is_refused_and_a_free_one_kept(busy_port, capsys):
    with pytest.raises(ConfigError, match=f"service.metrics_port = {busy_port} is in use on 127.0.0.1"):
        metrics_port_checked(with_port(busy_port), port_given=True)
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        free = probe.getsockname()[1]
    assert metrics_port_checked(with_port(free), port_given=False).service.metrics_port == free
    assert capsys.readouterr().err == ""


def test_the_port_counts_as_chosen_from_the_file_the_command_line_or_a_value_of_its_own():
    default = Config()
    assert not port_given(default, {}, ())
    assert port_given(default, {"service": {"metrics_port": 9100}}, ())
    assert port_given(default, {}, ("service.metrics_port=9100",))
    assert port_given(with_port(9200), {}, ())  # a resumed run's config.toml that holds a port of its own
    assert not port_given(default, {"service": {"metrics_host": "0.0.0.0"}}, ("run.episodes=3",))


def test_a_port_taken_after_the_check_falls_back_only_when_the_user_did_not_choose_it(busy_port, tmp_path, capsys,
                                                                                     ray_cluster):
    """Two runs started together (found by hand 2026-12-06: two `make run`s): both pass the check before Ray, the
    first binds 9100, the second's bind failed ("cannot be bound ... pass --metrics-port 0", exit 2)."""
    from cmcl.run.rundir import RunDirectory
    from services.launch import run_service

    config = make_tiny_config("maddpg", service=True, dir=str(tmp_path / "run"), episodes=4)
    config = replace(config, service=replace(config.service, metrics_port=busy_port, metrics_host="127.0.0.1"))
    run_dir = RunDirectory.create(config.run.dir, config)
    with pytest.raises(OSError, match=f"service.metrics_port = {busy_port} cannot be bound on 127.0.0.1"):
        run_service(config, run_dir, progress=None)
    summary = run_service(config, run_dir, progress=None, port_fallback=True)
    assert summary["metrics_port"] not in (busy_port, 0) and summary["episodes"] >= 4
    assert f"note: service.metrics_port = {busy_port} was taken on 127.0.0.1 since the check before Ray" in \
        capsys.readouterr().err


def test_the_request_says_whether_the_port_was_chosen(tmp_path):
    from cmcl.run.flags import RunRequest, port_given_by

    chosen = tmp_path / "chosen.toml"
    chosen.write_text("[service]\nmetrics_port = 9100\n")
    assert port_given_by(RunRequest(runner="service", config_file=str(chosen)), Config())
    assert not port_given_by(RunRequest(runner="service"), Config())
    assert port_given_by(RunRequest(runner="service", overrides=("service.metrics_port=9100",)), Config())
    assert not port_given_by(RunRequest(runner="service", config_file=str(chosen), resume_dir=str(tmp_path)), Config())
