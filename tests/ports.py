"""A free loopback TCP port for a test's server (the kernel picks it; a race with another binder is possible
but needs another process to take the same port between this call and the server's bind)."""

import socket


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
