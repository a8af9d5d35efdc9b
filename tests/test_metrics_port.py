"""The service's metrics port (cmcl.preflight.metrics_port_checked, cmcl.run_flags.port_given): a port the user chose
is refused when in use; the default one (9100, also Prometheus node_exporter's default) in use is replaced by a free
port with a note, so that `make run` does not fail on a machine that runs node_exporter (before, 2026-12-06: it
ended in "service.metrics_port = 9100 is in use ... pass --metrics-port 0", which `make run` cannot pass without
RUN_ARGS)."""

from __future__ import annotations

import socket
from dataclasses import replace

import pytest

from cmcl.config import Config, ConfigError
from cmcl.preflight import metrics_port_checked
from cmcl.run_flags import port_given
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
