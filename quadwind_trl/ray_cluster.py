"""Joining a Ray cluster from a command's ``--address auto|HOST:PORT``, with errors that name the
option: the pipeline's stages as Ray tasks (``recipes/reproduce.py --executor ray``) and a PPO
run's collection workers as Ray actors (``--collector ray``) connect the same way.

Ray is imported only when a function here needs it, so the modules that import this one run
without Ray installed.
"""
from __future__ import annotations

import contextlib
import socket
from typing import Iterator

#: seconds to wait for a TCP answer from ``--address HOST:PORT`` before calling it unreachable
#: (Ray's own connection attempt waits minutes before it gives up)
CONNECT_TIMEOUT_S = 5.0


class RayUnavailable(RuntimeError):
    """Ray is not installed, or the cluster named by ``--address`` cannot be reached."""


def import_ray(option: str, alternative: str):
    """The ``ray`` module, or :class:`RayUnavailable` saying that ``option`` (e.g. "--executor
    ray") needs it and what to do instead (``alternative``)."""
    try:
        import ray
    except ImportError:
        raise RayUnavailable(f"{option} needs Ray, which is not installed: pip install 'quadwind_trl[ray]', "
                             f"or {alternative}") from None
    return ray


def parse_address(address: str) -> tuple[str, int]:
    """``HOST:PORT`` of a Ray head node (the GCS port, 6379 unless ``ray start --port`` chose another)."""
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise RayUnavailable(f"--address {address!r}: expected 'auto' or HOST:PORT of the Ray head node "
                             "(PORT 1-65535, e.g. 10.0.0.1:6379)")
    return host, int(port)


def check_address(address: str | None) -> None:
    """Refuse a malformed ``address``, or a ``HOST:PORT`` where nothing answers, at once (None:
    a local instance; "auto": checked when Ray joins it)."""
    if address is None or address == "auto":
        return
    host, port = parse_address(address)
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as err:
        raise RayUnavailable(f"--address {address}: no Ray head node answers there ({err}); start one with "
                             "'ray start --head' on that machine, or check the host and port") from None


def connect(address: str | None, local_cpus: int, *, option: str, alternative: str) -> str:
    """Join the Ray cluster at ``address`` ("auto": the one ``ray start`` left on this machine, or
    ``RAY_ADDRESS``; ``HOST:PORT``: its head node), or with None start a local Ray instance of
    ``local_cpus`` CPUs for this command. Returns a line saying which, with the cluster's CPUs.
    ``option`` and ``alternative`` word the error when Ray is missing (:func:`import_ray`)."""
    ray = import_ray(option, alternative)
    if address is None:
        ray.init(num_cpus=local_cpus, include_dashboard=False)
        where = "a local Ray instance"
    else:
        check_address(address)
        try:
            ray.init(address=address)
        except ConnectionError as err:
            raise RayUnavailable(f"--address {address}: {err}") from None
        where = f"the Ray cluster at {address}"
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    return f"{where}: {len(nodes)} node{'s' if len(nodes) != 1 else ''}, {ray.cluster_resources().get('CPU', 0):g} CPUs"


@contextlib.contextmanager
def joined(address: str | None, local_cpus: int, *, option: str, alternative: str) -> Iterator[str | None]:
    """Inside: this process is connected to Ray. If it was already (a driver that connected first,
    a test), the context uses that connection and leaves it; else it :func:`connect`\\ s and
    disconnects at the end (stopping the local instance it started). Yields :func:`connect`'s
    line, or None for a connection made before."""
    ray = import_ray(option, alternative)
    if ray.is_initialized():
        yield None
        return
    line = connect(address, local_cpus, option=option, alternative=alternative)
    try:
        yield line
    finally:
        ray.shutdown()
