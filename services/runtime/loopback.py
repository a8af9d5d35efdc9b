"""An embedded Ray that listens on the loopback interface only.

Ray's servers (the GCS, the raylet's node and object managers, every worker's and actor's gRPC server, the dashboard
agent, the runtime-env agent and the metrics agent) bind to every interface (0.0.0.0 / ::) whenever the node's IP is
not a loopback address, and `ray.init` turns a loopback `_node_ip_address` into the machine's routable one
(`ray._private.services.resolve_ip_for_localhost`). The one switch Ray honours is the one it uses on macOS and
Windows: `RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0` makes the node's IP 127.0.0.1, and then every one of those servers binds
127.0.0.1 (IPv4-mapped `::ffff:127.0.0.1` for the C++ ones). A node started so cannot be joined by another machine,
which an embedded Ray never is; a cluster run (`--address`) keeps the cluster's own settings.

Where it sits: `services.launch.start_ray` calls `loopback_only()` right before an embedded `ray.init`, as does the
tests' session Ray (tests/conftest.py); tests/test_loopback.py lists the sockets a local service run listens on.
"""

from __future__ import annotations

import os
import sys

# Ray's switch (ray._private.ray_constants.ENABLE_RAY_CLUSTERS_ENV_VAR): "0" keeps a node on 127.0.0.1.
LOOPBACK_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}


def loopback_only() -> None:
    """Make the next embedded `ray.init` of this process bind every Ray server to 127.0.0.1.

    Sets `LOOPBACK_ENV` in this process's environment (Ray's processes inherit it), and, since Ray reads it once when
    `ray._private.ray_constants` is first imported, the constant too when that import has already happened."""
    os.environ.update(LOOPBACK_ENV)
    constants = sys.modules.get("ray._private.ray_constants")
    if constants is not None:
        constants.ENABLE_RAY_CLUSTER = False
