"""Several processes, one per machine (or per GPU), through JAX's multi-host runtime.

JAX must join the run before it computes anything, and importing jaxpose computes
(evosax builds constants at import).  So the run is joined when jaxpose is
imported, if ``JAXPOSE_DISTRIBUTED=1`` is set (:func:`initialize_from_environment`,
called by ``jaxpose/__init__.py``), or by the user calling
:func:`jax.distributed.initialize` before importing jaxpose.

:func:`initialize` starts :func:`jax.distributed.initialize` from explicit settings
or the environment: ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES``,
``JAX_PROCESS_ID``, or what JAX detects itself on a cluster (SLURM, Open MPI,
Kubernetes, TPU pods).  After it, ``jax.devices()`` lists every process's devices
and :func:`jaxpose.parallel.fit_batch` runs one program over all of them; each
process reads its own share of the inputs (:func:`share`) and writes its own
results.  No pool, no RPC of jaxpose's own: the coordinator is JAX's.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TypeVar

from .errors import ConfigError

T = TypeVar("T")

ENV = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")
SWITCH = "JAXPOSE_DISTRIBUTED"  # 1: join the run when jaxpose is imported

_startup_error: ConfigError | None = None


def _env_int(name: str) -> int | None:
    value = os.environ.get(name)
    if value in (None, ""):
        return None
    try:
        return int(value)
    except ValueError:
        raise ConfigError(f"environment variable {name}={value!r}: not an integer") from None


def settings(coordinator: str | None = None, num_processes: int | None = None,
             process_id: int | None = None) -> tuple[str | None, int | None, int | None]:
    """The coordinator address, process count and process id: the arguments, else the
    environment (:data:`ENV`); ``None`` where neither says (JAX then asks the cluster).
    :class:`ConfigError` for impossible values."""
    coordinator = coordinator or os.environ.get(ENV[0]) or None
    num_processes = _env_int(ENV[1]) if num_processes is None else num_processes
    process_id = _env_int(ENV[2]) if process_id is None else process_id
    if coordinator is not None:
        host, sep, port = coordinator.rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ConfigError(f"coordinator {coordinator!r}: give HOST:PORT (e.g. node0:8476)")
    if num_processes is not None and num_processes < 1:
        raise ConfigError(f"num_processes must be >= 1, got {num_processes}")
    if process_id is not None and (process_id < 0 or (num_processes is not None and process_id >= num_processes)):
        raise ConfigError(f"process_id must lie within 0 .. num_processes-1 ({num_processes}), got {process_id}")
    return coordinator, num_processes, process_id


def initialize(coordinator: str | None = None, num_processes: int | None = None,
               process_id: int | None = None, timeout: int = 300) -> None:
    """Join the processes of one run (every process calls this before JAX computes
    anything).  On CPU the processes exchange data through gloo (JAX's CPU
    collectives).  A single process (``num_processes == 1``) needs no coordinator
    and starts nothing."""
    coordinator, num_processes, process_id = settings(coordinator, num_processes, process_id)
    if num_processes == 1:
        return
    import jax

    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator, num_processes, process_id, initialization_timeout=timeout)


def initialize_from_environment() -> None:
    """:func:`initialize` from the environment when ``JAXPOSE_DISTRIBUTED`` is ``1``
    (run at import: a bad setting is kept and raised by :func:`check`)."""
    global _startup_error
    if os.environ.get(SWITCH, "0").strip().lower() not in ("1", "true", "yes"):
        return
    try:
        initialize()
    except ConfigError as e:
        _startup_error = ConfigError(f"{SWITCH}=1: {e}")


def check() -> None:
    """Raise the error of joining the run at import, if there was one."""
    if _startup_error is not None:
        raise _startup_error


def shutdown() -> None:
    """Leave the run (after the last collective program); nothing if not initialized."""
    import jax

    if jax.process_count() > 1:
        jax.distributed.shutdown()


def share(items: Sequence[T], index: int | None = None, count: int | None = None) -> list[T]:
    """This process's share of ``items``: every ``count``-th from ``index`` (default
    this process's index and the process count), so shares differ by one item at
    most and every process computes them alike from the same list."""
    if index is None or count is None:
        import jax

        index, count = jax.process_index(), jax.process_count()
    return list(items[index::count])


def barrier(name: str) -> None:
    """Wait until every process reaches this point (JAX's coordination service)."""
    import jax

    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)


__all__ = ["ENV", "SWITCH", "barrier", "check", "initialize", "initialize_from_environment", "settings", "share",
           "shutdown"]
