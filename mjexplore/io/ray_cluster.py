"""Joining a Ray cluster (or starting a local instance) and running tasks on it.

``train --ray``, ``bench --ray`` and ``train-predictor --ray`` take the same address:
nothing (a fresh instance on this machine), ``auto`` (the cluster this machine started or
joined with ``ray start``) or a head's ``HOST:PORT``. :func:`connect` joins it with errors
that say how to make a cluster; :func:`map_unordered` runs one function over many argument
tuples as Ray tasks (one CPU each) and yields each outcome as it finishes, a task's own
exception or a lost worker included, so that one broken task never ends the others.

Every machine of a cluster runs the code of its own mjexplore checkout: :func:`map_unordered`
returns each task's git revision with its result, and callers refuse results made by
another revision than their own.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import ray

from mjexplore.errors import UserInputError
from mjexplore.io.provenance import git_revision

log = logging.getLogger(__name__)

LOCAL = "local"  # A fresh Ray instance on this machine.
AUTO = "auto"  # The cluster this machine belongs to (the last `ray start` here).
HOW_TO_START = ("start one with `ray start --head --port=6379` on the head machine and "
                "`ray start --address=HEAD_IP:6379` on each other machine, then run on the "
                "head with --ray auto (see the guide's page 'Scaling out')")
TOKEN_HELP = ("if the head uses token authentication (`ray start --head` says so), export "
              "RAY_AUTH_MODE=token and RAY_AUTH_TOKEN=<what `ray get-auth-token` prints on the "
              "head> here")
CONNECT_TIMEOUT_S = 5.0  # Ray itself retries an unreachable address for minutes.
RETRIES = 2  # Re-runs of a task whose worker process or machine died.


def connect(address: str, min_cpus: int = 1, local_cpus: int | None = None,
            what: str = "tasks", fewer: str | None = None) -> bool:
    """Joins the Ray cluster at ``address`` or starts a local instance.

    Args:
        address: 'local' (a fresh instance on this machine), 'auto' (the cluster this
            machine joined with ``ray start``) or a head's 'HOST:PORT'.
        min_cpus: CPUs the caller needs at once (e.g. one per training env); a cluster with
            fewer is refused. A local instance gets at least this many.
        local_cpus: A local instance's CPUs (None: this machine's cores).
        what: What needs the ``min_cpus``, for the message (e.g. 'envs').
        fewer: The option that asks for fewer, for the message (e.g. '--n-envs').

    Returns:
        Whether this call initialised Ray (its caller then calls ``ray.shutdown()``); False
        when this process had already joined a Ray instance, which is then used as it is.

    Raises:
        UserInputError: No cluster at ``address``, or too few CPUs in it.
    """
    if ray.is_initialized():
        log.info("using the Ray instance this process already joined")
        joined = False
    elif address == LOCAL:
        cpus = local_cpus or os.cpu_count() or 1
        if min_cpus > cpus:
            log.warning("%d tasks at once on %d CPUs: they share the cores", min_cpus, cpus)
        ray.init(address=LOCAL, num_cpus=max(cpus, min_cpus), include_dashboard=False)
        joined = True
    else:
        if address != AUTO:
            _check_reachable(address)
        try:
            ray.init(address=address)
        except (ConnectionError, ValueError, ray.exceptions.AuthenticationError) as exc:
            raise UserInputError(f"--ray {address}: Ray could not join a cluster there "
                                 f"({ray_cause(exc)}); {TOKEN_HELP}; without a cluster, "
                                 f"{HOW_TO_START}.") from None
        joined = True
    resources = ray.cluster_resources()
    nodes = [n for n in ray.nodes() if n["Alive"]]
    cpus = resources.get("CPU", 0.0)
    log.info("Ray: %d node(s) (%s), %g CPUs, %.1f GiB memory", len(nodes),
             ", ".join(n["NodeManagerAddress"] for n in nodes), cpus,
             resources.get("memory", 0.0) / 2**30)
    if cpus < min_cpus:
        if joined:
            ray.shutdown()
        raise UserInputError(f"the Ray cluster has {cpus:g} CPUs and {min_cpus} {what} need one "
                             f"each: {f'lower {fewer}, or ' if fewer else ''}add machines with "
                             "`ray start --address=HEAD_IP:6379` on each.")
    return joined


def _check_reachable(address: str) -> None:
    """Raises UserInputError unless something listens at ``address`` ('HOST:PORT')."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise UserInputError(f"--ray {address!r} is not a Ray address: give the head's "
                             "HOST:PORT (e.g. 10.0.0.1:6379), auto, or nothing for a local "
                             f"instance. To make a cluster, {HOW_TO_START}.")
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise UserInputError(f"--ray {address}: no Ray cluster answers there "
                             f"({exc.strerror or exc}); {HOW_TO_START}.") from None


def ray_cause(exc: BaseException) -> str:
    """The last line of a Ray error (the remote exception), for one-paragraph messages."""
    lines = [line for line in str(exc).splitlines() if line.strip()]
    return lines[-1].strip() if lines else type(exc).__name__


def _task(initializer: Callable[[], None] | None, fn: Callable[..., Any],
          *args: Any) -> tuple[str, Any]:
    """A task's body: (this machine's mjexplore revision, ``fn(*args)``)."""
    if initializer is not None:
        initializer()
    return git_revision(), fn(*args)


def map_unordered(fn: Callable[..., Any], calls: Sequence[tuple], *,
                  initializer: Callable[[], None] | None = None,
                  retries: int = RETRIES) -> Iterator[tuple[int, Any, BaseException | None]]:
    """Runs ``fn(*call)`` for every call as a Ray task (one CPU each) on the joined Ray
    instance; yields ``(index of the call, result, None)`` or ``(index, None, error)`` in
    the order they finish.

    Arguments that are ``ray.ObjectRef`` at the top level of a call (e.g. files put once
    with ``ray.put`` and shared by many calls) arrive in ``fn`` as their values. A task
    whose worker process or machine dies is run again up to ``retries`` times; after that
    (and for an exception ``fn`` raised) its error is yielded. A result made by a machine
    whose mjexplore checkout is at another revision than this one's is yielded as a
    :class:`~mjexplore.errors.UserInputError`.

    Closing the iterator early (or Ctrl-C in the loop that reads it) cancels the tasks not
    yet finished.

    Args:
        fn: A module-level function (pickled by reference: every machine imports it).
        calls: Each task's positional arguments.
        initializer: Called in the worker before each task (e.g. thread limits).
        retries: Re-runs of a task whose worker died.
    """
    remote = ray.remote(num_cpus=1, max_retries=retries, retry_exceptions=False)(_task)
    pending = {remote.remote(initializer, fn, *call): i for i, call in enumerate(calls)}
    mine = git_revision()
    try:
        while pending:
            [ref], _ = ray.wait(list(pending), num_returns=1)
            index = pending.pop(ref)
            try:
                revision, result = ray.get(ref)
            except ray.exceptions.RayTaskError as exc:  # fn raised: its own exception.
                cause = exc.as_instanceof_cause()
                yield index, None, cause if isinstance(cause, Exception) else exc
                continue
            except ray.exceptions.RayError as exc:  # A lost worker or machine, a cancel.
                yield index, None, exc
                continue
            if revision != mine:
                yield index, None, UserInputError(
                    f"a Ray worker's mjexplore checkout is at {revision}, this machine's at "
                    f"{mine}: check out and install the same revision on every machine.")
                continue
            yield index, result, None
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
