"""The Ray instance a batch runs on: connecting to it, and checking that a clip's tasks fit.

Without --ray-address a new local instance is started (never a cluster found on the machine);
with one, the batch connects to that cluster: `host:port` of its head, `ray://host:port` of its
Ray Client server (which needs the `ray[client]` extra) or `auto` (the cluster started on this
machine with `ray start`). An address that is malformed, that nothing answers at, or whose
cluster Ray cannot join is one SurgsplatError naming --ray-address.

Each task of a clip declares --cpus-per-clip CPUs and --memory-gb of memory, which Ray must
find on one node: a task that no node can hold would wait forever. The request is checked
against this machine before a local instance starts, and against the nodes of the instance or
cluster once connected (Ray keeps part of a node's memory for its object store).
"""

from __future__ import annotations

import importlib.util
import logging
import os
import signal
import socket
from dataclasses import dataclass

from surgsplat.errors import SurgsplatError

GIB = 2**30
CONNECT_SECONDS = 5.0
"""How long the head of a cluster has to accept a TCP connection before Ray is asked to join
it (Ray itself retries an address where nothing answers for minutes)."""
RAY_CLIENT_SCHEME = "ray://"


@dataclass(frozen=True)
class Node:
    """What one Ray node offers tasks."""

    cpus: float
    memory: float  # bytes


def ray_module():
    """The ray package, or a SurgsplatError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise SurgsplatError("surgsplat batch needs Ray: pip install 'surgsplat[batch]'") \
            from None
    return ray


def check_local_request(cpus_per_clip: int, memory_gb: float, num_cpus: int | None) -> None:
    """SurgsplatError unless this machine (or a local instance of `num_cpus` CPUs) can hold one
    task of a clip; checked before Ray starts."""
    if num_cpus is not None:
        _check_amount("--cpus-per-clip", cpus_per_clip, "--num-cpus", f"{num_cpus}", num_cpus)
    cpus = os.cpu_count() or 1
    _check_amount("--cpus-per-clip", cpus_per_clip, "this machine's CPUs", f"{cpus}", cpus)
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    _check_amount("--memory-gb", memory_gb, "this machine's memory", f"{memory / GIB:.1f} GiB",
                  memory / GIB)


def check_nodes_hold(nodes: list[Node], cpus_per_clip: int, memory_gb: float,
                     where: str) -> None:
    """SurgsplatError unless one of `nodes` (those of `where`, e.g. "the local Ray instance")
    has the CPUs and the memory that each task of a clip declares."""
    memory = memory_gb * GIB
    if any(node.cpus >= cpus_per_clip and node.memory >= memory for node in nodes):
        return
    of = f"any node of {where}" if len(nodes) > 1 else where
    most_cpus = max((node.cpus for node in nodes), default=0.0)
    most_memory = max((node.memory for node in nodes), default=0.0)
    _check_amount("--cpus-per-clip", cpus_per_clip, f"the CPUs of {of}", f"{most_cpus:g}",
                  most_cpus)
    _check_amount("--memory-gb", memory_gb, f"the memory of {of}",
                  f"{most_memory / GIB:.1f} GiB", most_memory / GIB)
    raise SurgsplatError(f"--cpus-per-clip {cpus_per_clip} with --memory-gb {memory_gb:.12g}: "
                         f"no node of {where} has both; no task of a clip could ever start")


def _check_amount(option: str, value: float, limit_name: str, limit_text: str,
                  limit: float) -> None:
    """SurgsplatError naming `option` when its `value` exceeds `limit` (`limit_name`, shown as
    `limit_text`)."""
    if value > limit:
        raise SurgsplatError(f"{option} {value:.12g} is more than {limit_name} ({limit_text}); "
                             "no task of a clip could ever start")


def ray_nodes(ray) -> list[Node]:
    """The live nodes of the Ray instance this process is connected to."""
    return [Node(node["Resources"].get("CPU", 0.0), node["Resources"].get("memory", 0.0))
            for node in ray.nodes() if node.get("Alive")]


def connect(ray, ray_address: str | None, num_cpus: int | None) -> str:
    """Start a local Ray instance (of `num_cpus` CPUs, default all), or join the cluster at
    `ray_address`; returns what the batch runs on, for messages ("the local Ray instance",
    "the Ray cluster at ADDRESS")."""
    if ray_address is None:
        start_ray(ray, address="local", num_cpus=num_cpus)
        return "the local Ray instance"
    check_reachable(ray_address)
    try:
        start_ray(ray, address=ray_address)
    except (ConnectionError, RuntimeError, ray.exceptions.RayError) as err:  # cannot join it
        reason = "no Ray cluster is running on this machine (start one with `ray start " \
                 "--head`, or omit --ray-address for a local instance)" \
            if ray_address == "auto" else str(err).strip().splitlines()[0]
        raise SurgsplatError(f"--ray-address {ray_address}: {reason}") from None
    return f"the Ray cluster at {ray_address}"


def check_reachable(ray_address: str) -> None:
    """SurgsplatError unless `ray_address` is `auto`, or `host:port` or `ray://host:port`
    accepting a TCP connection (a `ray://` address also needs Ray Client installed)."""
    if ray_address == "auto":
        return
    address = ray_address
    if address.startswith(RAY_CLIENT_SCHEME):
        if importlib.util.find_spec("grpc") is None:
            raise SurgsplatError(f"--ray-address {ray_address}: a ray:// address needs Ray "
                                 'Client: pip install "ray[client]"')
        address = address.removeprefix(RAY_CLIENT_SCHEME)
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise SurgsplatError(f"--ray-address {ray_address}: expected host:port (the head "
                             "node's GCS), ray://host:port (its Ray Client server) or auto")
    try:
        socket.create_connection((host.strip("[]"), int(port)), CONNECT_SECONDS).close()
    except OSError as err:
        raise SurgsplatError(f"--ray-address {ray_address}: cannot reach {host}:{port} "
                             f"({err.strerror or err}); is the Ray cluster running?") from None


def start_ray(ray, **options) -> None:
    """ray.init(**options) without Ray's start-up warnings (such as its notice that a new local
    instance uses token authentication), which a failure line would follow; this process's
    SIGTERM handler is kept: Ray replaces it with its own, which exits at once (and prints a
    native stack dump), where surgsplat's turns SIGTERM into a stop that the batch reports in
    one line."""
    handler = signal.getsignal(signal.SIGTERM)
    ray_logger = logging.getLogger("ray")
    level = ray_logger.level
    ray_logger.setLevel(logging.ERROR)
    try:
        ray.init(**options, include_dashboard=False, log_to_driver=False,
                 configure_logging=False)
    finally:
        ray_logger.setLevel(level)
    if handler is not None:  # None: a handler that Python did not install
        signal.signal(signal.SIGTERM, handler)
