"""Studies on a Dask cluster (the `cluster` extra; docs/cluster.md): a study's settings x seeds split
into blocks, one task per block, each block's result handed back as it finishes.

The only module that imports the engine (dask.distributed), and only once a study names a cluster.
Each insect's run depends only on its own setting and seed (its arena, heading and netlogo order
come from its seed; no random stream is shared across a population), so any split gives one
process's result, bit for bit. A worker lost mid-block: the scheduler runs the block again on
another worker.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import re
import socket
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import CancelledError, Future
from contextlib import contextmanager
from functools import partial
from typing import cast

import numpy as np

log = logging.getLogger("spikinglab.cluster")
CONNECT_S = 5  # a scheduler that does not answer within this is reported
# insects per block, about: smaller blocks run slower per insect; more blocks show progress sooner,
# balance the workers and lose less when a worker is lost
BLOCK = 16
ADDRESS = re.compile(r"tcp://(\[[0-9a-fA-F:]+\]|[\w.-]+):(\d{1,5})")


class ClusterError(Exception):
    """The cluster cannot be used (the extra missing, no scheduler answering); one line."""


def cluster_address(text: str) -> str:
    """A scheduler's address, tcp://HOST:PORT; ValueError says what was wrong."""
    found = ADDRESS.fullmatch(text) if isinstance(text, str) else None
    if not found or not 0 < int(found[2]) < 65536:
        raise ValueError(f"expected a Dask scheduler's address tcp://HOST:PORT, got {text!r}")
    return text


def address_option(text: str) -> str:
    """A command line's --cluster option: cluster_address, refused as argparse refuses (exit 2)."""
    try:
        return cluster_address(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def check_cluster(address: str) -> None:
    """ClusterError unless the extra is installed and a Dask scheduler answers at `address`: a
    command calls it before its study shows progress, a study again as it connects."""
    found = ADDRESS.fullmatch(cluster_address(address))
    assert found is not None  # cluster_address checked it
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise ClusterError("a cluster needs Dask distributed: pip install 'spikinglab[cluster]'") from None
    require_scheduler(address, found[1].strip("[]"), int(found[2]))


@contextmanager
def connected(address: str):
    """A Dask client of the scheduler at `address`, closed (and its unfinished tasks cancelled) on leaving."""
    check_cluster(address)
    from distributed import Client

    try:
        client = Client(address, timeout=CONNECT_S, set_as_default=False)
    except (OSError, TimeoutError) as e:
        raise unanswered(address, e) from None
    except Exception as e:  # it speaks Dask's protocol, or seemed to, but is no scheduler
        raise ClusterError(f"{address} answered, but not as a Dask scheduler ({type(e).__name__})") from None
    client_log, quiet = logging.getLogger("distributed.client"), Quiet()  # a filter each: studies may overlap
    client_log.addFilter(quiet)  # its reconnect's traceback: the study's ClusterError says what happened
    try:
        with client:
            yield client
    finally:
        client_log.removeFilter(quiet)


class Quiet(logging.Filter):
    """Drops the records of Dask's client below CRITICAL while a study has it."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno >= logging.CRITICAL


def unanswered(address: str, e: OSError | TimeoutError) -> ClusterError:
    """Why nothing answered at `address`: a refusal comes at once, so it claims no wait."""
    if isinstance(e, ConnectionRefusedError):
        return ClusterError(f"no Dask scheduler at {address}: the connection was refused ({type(e).__name__})")
    if isinstance(e, TimeoutError):
        return ClusterError(f"no Dask scheduler answers at {address} within {CONNECT_S} s ({type(e).__name__})")
    return ClusterError(f"no Dask scheduler answers at {address}: {e.strerror or e} ({type(e).__name__})")


def require_scheduler(address: str, host: str, port: int) -> None:
    """ClusterError unless a Dask scheduler at host:port says who it is within CONNECT_S: the
    client's connect waits for Dask's greeting without end (a silent port, such as the scheduler's
    dashboard given for the scheduler, would hang a study), reads any other server's bytes as
    message frames, and takes a worker's address for a scheduler's until its first call fails."""
    try:
        socket.create_connection((host, port), timeout=CONNECT_S).close()
    except socket.gaierror:
        raise ClusterError(f"no host {host!r} (in {address}): the name does not resolve") from None
    except OSError as e:  # refused, unreachable, or no connection within CONNECT_S
        raise unanswered(address, e) from None
    answer: Future = Future()

    def ask() -> None:  # in a loop of its own: the caller may be in one (Jupyter)
        try:
            answer.set_result(asyncio.run(identity(address)))
        except BaseException as e:
            answer.set_exception(e)

    # a daemon thread: Ctrl-C ends the study at once, not when the check has timed out
    threading.Thread(target=ask, name="dask-scheduler-check", daemon=True).start()
    try:
        kind = answer.result()
    except TimeoutError:
        raise ClusterError(
            f"something at {address} accepts connections but does not answer as Dask does within "
            f"{CONNECT_S} s: not a Dask scheduler (its dashboard's port?)"
        ) from None
    except OSError:  # Dask's CommClosedError among them: what a tunnel does when nothing is behind it
        raise ClusterError(
            f"something at {address} took the connection and closed it without answering as Dask does: "
            f"no Dask scheduler there (behind a tunnel or port forward, it may be down)"
        ) from None
    except Exception:  # another protocol's bytes read as Dask's frames: any error (a MemoryError too)
        raise ClusterError(
            f"something at {address} answered, but not in Dask's protocol: not a Dask scheduler"
        ) from None
    if kind != "Scheduler":
        raise ClusterError(f"{address} is a Dask {kind}, not a scheduler: give the scheduler's address")


async def identity(address: str) -> str:
    """What the Dask process at `address` says it is ("Scheduler", "Worker", "Nanny")."""
    from distributed.comm.core import connect

    async def ask() -> str:
        # Dask's connect tries again while connections are closed at once (a tunnel with nothing behind
        # it); within a shorter time than the whole check's, so that it is told from a silent port
        comm = await connect(address, timeout=CONNECT_S / 2)
        try:
            await comm.write({"op": "identity", "reply": True})
            return str((await comm.read()).get("type"))
        finally:
            await comm.close()

    return await asyncio.wait_for(ask(), CONNECT_S)


def split(n: int, parts: int) -> list[range]:
    """0..n-1 in `parts` contiguous ranges whose lengths differ by at most one."""
    return [range(k * n // parts, (k + 1) * n // parts) for k in range(parts)]


def blocks(settings: int, seeds: int, threads: int) -> list[tuple[range, range]]:
    """The study's settings x seeds as rectangles (settings, seed positions): at least one per worker
    thread, else about BLOCK insects each; whole settings where there are enough of them."""
    count = min(settings * seeds, max(threads, settings * seeds // BLOCK, 1))
    if count <= settings:
        return [(s, range(seeds)) for s in split(settings, count)]
    per_setting = min(seeds, -(-count // settings))
    return [(s, j) for s in split(settings, settings) for j in split(seeds, per_setting)]


def in_blocks(
    address: str, task: Callable[[range, range], object], settings: int, seeds: int
) -> Iterator[tuple[range, range, object]]:
    """`task(settings, seed positions)` on the cluster, once per block; (settings, seed positions,
    result) as each block finishes. `task` is pickled: a module-level function or a partial of one."""
    with connected(address) as client:
        from distributed import as_completed  # after connected(): it says when the extra is missing
        from distributed.scheduler import KilledWorker

        threads = worker_threads(client, address)
        futures = {client.submit(task, s, j, pure=False): (s, j) for s, j in blocks(settings, seeds, threads)}
        done = 0
        try:
            for future in as_completed(futures, loop=client.loop):
                yield (*futures[future], future.result())
                done += 1
        except CancelledError as e:  # every block cancelled: the scheduler lost, as a rule
            raise ClusterError(
                f"the study on {address} was cancelled after {done} of {len(futures)} blocks "
                f"({getattr(e, 'reason', 'no reason given')}): start the cluster again, then the study"
            ) from None
        except KilledWorker as e:  # the scheduler gave up on a block whose workers all died running it
            raise ClusterError(f"the study on {address} stopped after {done} of {len(futures)} blocks: {e}") from None


def worker_threads(client, address: str) -> int:
    """The cluster's worker threads, once it has a worker: a study cut into blocks for none would be
    one block per BLOCK insects whatever the cluster becomes. Says so while it waits."""
    threads = sum(cast(dict, client.nthreads()).values())  # a dict: the client is synchronous
    if not threads:
        log.warning("no worker on the cluster at %s yet: the study waits for one (docs/cluster.md)", address)
    while not threads:
        try:
            client.wait_for_workers(1, timeout=CONNECT_S)
        except TimeoutError:
            pass
        except OSError as e:  # the scheduler gone while waiting
            raise ClusterError(
                f"the scheduler at {address} went away while the study waited for a worker ({e})"
            ) from None
        threads = sum(cast(dict, client.nthreads()).values())
    return threads


def settings_of(params: Mapping, chosen: range) -> dict:
    """The per-agent parameter columns of the chosen settings (a single number stays one)."""
    return {k: v if np.size(v) == 1 else np.asarray(v)[chosen.start : chosen.stop] for k, v in params.items()}


def evaluate_block(params: Mapping, ticks: int, seeds: Sequence[int], options: Mapping, chosen: range, at: range):
    """One block of `evaluate_on`, on a worker: the chosen settings on the seeds at positions `at`."""
    from services.loop import evaluate

    return evaluate(settings_of(params, chosen), ticks, [seeds[j] for j in at], **options)


def evaluate_on(
    address: str,
    params: Mapping,
    ticks: int,
    seeds: Sequence[int],
    on_block: Callable[[int], object] | None = None,
    **options,
) -> dict[str, np.ndarray]:
    """services.loop.evaluate on the cluster at `address`: the same arrays, bit for bit.
    `on_block(insects)` is called as each block finishes, with its number of insects."""
    from services.params import agent_columns, setting_count

    n = setting_count(params)
    agent_columns(n, params)  # a bad column is refused here, before anything is sent
    out: dict[str, np.ndarray] = {}
    task = partial(evaluate_block, dict(params), ticks, list(seeds), options)
    for chosen, at, result in in_blocks(address, task, n, len(seeds)):
        for name, values in result.items():  # type: ignore[union-attr]
            out.setdefault(name, np.empty((n, len(seeds)), values.dtype))[
                chosen.start : chosen.stop, at.start : at.stop
            ] = values
        if on_block is not None:
            on_block(len(chosen) * len(at))
    return out
