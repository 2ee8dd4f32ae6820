"""The one way simtest reaches a Dask distributed cluster: ``--scheduler tcp://HOST:PORT``.

The address is checked before anything connects, the connection waits at most :data:`CONNECT_TIMEOUT`,
and Dask (``pip install "simtest[dask]"``) is imported only when a scheduler is given.
"""

from __future__ import annotations

import socket

from simtest._lazy import require

__all__ = ["CONNECT_TIMEOUT", "SchedulerError", "check_scheduler_address", "connect"]

#: How long ``--scheduler`` waits for the Dask scheduler to answer (a reachable scheduler answers
#: in milliseconds; a wrong address should fail within a few seconds).
CONNECT_TIMEOUT = "3s"

#: How long the TCP probe before Dask's client waits, s: a port nothing listens on refuses at once; silence is Dask's.
PROBE_TIMEOUT_S = 1.0

#: The protocols of Dask's communication layer that an address may name.
PROTOCOLS = ("tcp", "tls", "ucx", "ws", "wss", "inproc")


class SchedulerError(ValueError):
    """A scheduler address that cannot work, or a scheduler that does not answer (one line)."""


def check_scheduler_address(address: str) -> tuple[str, str | None, int | None]:
    """Refuse a scheduler address that cannot work, before trying to connect.

    Parameters
    ----------
    address : str
        ``PROTOCOL://HOST:PORT``, e.g. ``tcp://127.0.0.1:8786``.

    Returns
    -------
    (protocol, host, port) : tuple
        As parsed (host and port None for ``inproc``).

    Raises
    ------
    SchedulerError
        If the address has no known protocol or port, or its host name does not resolve; the
        message names the address and why.
    simtest._lazy.MissingBackend
        If Dask's ``distributed`` is not installed (the message names the extra).
    """
    addressing = require("distributed.comm.addressing", purpose="--scheduler")
    where = f"--scheduler {address!r}"
    if "://" not in address:
        raise SchedulerError(f"{where}: not a scheduler address (expected tcp://HOST:PORT, e.g. "
                             "tcp://127.0.0.1:8786)")
    try:
        proto, loc = addressing.parse_address(address, strict=True)
        if proto not in PROTOCOLS:
            raise ValueError(f"unknown protocol {proto!r}")
        host, port = addressing.parse_host_port(loc) if proto != "inproc" else (None, None)
    except (ValueError, TypeError) as exc:
        raise SchedulerError(f"{where}: not a scheduler address: {exc}") from None
    if host is not None:
        try:
            socket.getaddrinfo(host, port)
        except (OSError, UnicodeError) as exc:
            raise SchedulerError(f"{where}: host {host!r} does not resolve: {exc}") from None
    return proto, host, port


def connect(address: str, timeout: str | None = None):
    """A ``distributed.Client`` of the cluster at ``address`` (not made the default client).

    Parameters
    ----------
    address : str
        The scheduler's address (:func:`check_scheduler_address`).
    timeout : str, optional
        How long to wait for the scheduler (Dask's time string); default :data:`CONNECT_TIMEOUT`.

    Returns
    -------
    distributed.Client
        Close it when done.

    Raises
    ------
    SchedulerError
        A bad address, a refused connection (nothing listens at that port), or no answer within the time-out.
    """
    proto, host, port = check_scheduler_address(address)
    wait = CONNECT_TIMEOUT if timeout is None else timeout
    if proto == "tcp":  # a port nothing listens on refuses at once, where Dask retries until the time-out
        try:
            socket.create_connection((host, port), timeout=PROBE_TIMEOUT_S).close()
        except ConnectionRefusedError:
            raise SchedulerError(f"--scheduler {address}: cannot connect: the connection was refused (nothing "
                                 "listens at that port)") from None
        except OSError:
            pass  # (no answer yet: Dask's wait decides)
    client_cls = require("distributed", purpose="--scheduler").Client
    try:
        return client_cls(address, timeout=wait, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise SchedulerError(f"--scheduler {address}: cannot connect within {wait}: {exc}") from None
