"""Studies on a Dask cluster (services/cluster.py): a scheduler and two workers started here as
separate processes, as on several machines. A study split into blocks gives one process's arrays
bit for bit, and still does when a worker is killed (kill -9) while it holds a block: the scheduler
runs that block again on another worker. Without a cluster, nothing of Dask (or Ray) is imported."""

import contextlib
import json
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import cast

import numpy as np
import pytest
from distributed import Client

from services import sweep
from services.cluster import ClusterError, blocks
from services.loop import evaluate

from .processes import ROOT

# 2 settings x 3 seeds (not in order, so that a block's seeds are placed by position), a learning
# time short enough that some insects learn within the run
PARAMS = {"a_plus": [0.02, 0.04], "a_minus": [0.02, 0.04], "w_max": 15}
SEEDS = [5, 0, 7]
OPTIONS: dict = dict(ticks=3000, seeds=SEEDS, learned_after=500)
LONG: dict = OPTIONS | {"ticks": 2_000_000}  # a block that is still running when its scheduler is lost


def dask(*args: str, log) -> subprocess.Popen:
    """A `dask scheduler` or `dask worker` process from this environment, started in the repository."""
    command = [sys.executable, "-m", f"distributed.cli.dask_{args[0]}", *args[1:], "--no-dashboard"]
    return subprocess.Popen(command, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)


def worker(address: str, name: str, folder) -> subprocess.Popen:
    """A worker of one thread, without a nanny: the process killed is the worker itself."""
    return dask(
        "worker", address, "--nthreads", "1", "--no-nanny", "--name", name, log=open(folder / f"{name}.log", "w")
    )


def start_scheduler(folder) -> tuple[subprocess.Popen, str]:
    """A scheduler on the loopback, its log in `folder`; (its process, its address)."""
    file = folder / "scheduler.json"
    args = ("scheduler", "--host", "127.0.0.1", "--port", "0", "--scheduler-file", str(file))
    process = dask(*args, log=open(folder / "scheduler.log", "w"))
    started = time.monotonic()
    while not file.exists() and process.poll() is None and time.monotonic() - started < 60:
        time.sleep(0.1)
    return process, json.loads(file.read_text())["address"]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A scheduler on the loopback and two workers, each a process; (address, folder of their logs)."""
    folder = tmp_path_factory.mktemp("cluster")
    scheduler, address = start_scheduler(folder)
    processes = [scheduler]
    try:
        processes += [worker(address, f"worker-{k}", folder) for k in range(2)]
        with Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=120)
        yield address, folder
    finally:
        for p in processes[:0:-1] + processes[:1]:  # the workers first: a worker closing with its scheduler may hang
            stop(p)


def stop(process: subprocess.Popen) -> None:
    process.terminate()
    try:
        process.wait(20)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(10)


@pytest.fixture(scope="module")
def one_process():
    """The study in this process: the arrays every split must give."""
    return evaluate(PARAMS, **OPTIONS)


def assert_identical(found: dict, expected: dict) -> None:
    assert list(found) == list(expected)
    for name, values in expected.items():
        assert found[name].dtype == values.dtype and np.array_equal(found[name], values), name
    assert (expected["learning_time"] >= 0).any() and (expected["learning_time"] < 0).any()  # both kinds met


@pytest.mark.parametrize("settings, seeds, threads", [(2, 3, 2), (1, 40, 2), (3, 2, 5), (100, 4, 8), (7, 1, 1)])
def test_blocks_cover_every_insect_once(settings, seeds, threads):
    found = blocks(settings, seeds, threads)
    insects = sorted((k, j) for chosen, at in found for k in chosen for j in at)
    assert insects == [(k, j) for k in range(settings) for j in range(seeds)]
    assert len(found) >= min(threads, settings * seeds)  # every thread gets a block


def test_without_a_cluster_neither_dask_nor_ray_is_imported():
    """A fresh interpreter imports the sweep and runs a plain evaluate: no module of either engine."""
    code = (
        "import json, sys, services.sweep\n"
        "from spikinglab import evaluate\n"
        "evaluate({'a_plus': 0.02}, 1000, range(1))\n"
        "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules} & {'dask', 'distributed', 'ray'})))"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(done.stdout.splitlines()[-1]) == []


def test_a_study_in_blocks_on_two_workers_is_the_one_process_study(cluster, one_process):
    address, _ = cluster
    finished = []
    found = evaluate(PARAMS, **OPTIONS, cluster=address, on_block=finished.append)
    assert_identical(found, one_process)
    assert len(finished) == 2 and sum(finished) == 6  # a block per worker, each reported as it finished


def test_a_worker_killed_mid_study_leaves_the_result_identical(cluster, one_process):
    """A third worker joins; once it is running a block (its first: importing and running the loop
    takes a while), kill -9: the scheduler runs that block again and the study ends on the other two."""
    address, folder = cluster
    victim = worker(address, "victim", folder)
    try:
        with Client(address, timeout=30) as client, ThreadPoolExecutor(1) as pool:
            client.wait_for_workers(3, timeout=120)
            (victim_address,) = [
                a for a, w in client.scheduler_info(n_workers=-1)["workers"].items() if w["name"] == "victim"
            ]

            def running() -> int:  # blocks the victim is executing now
                counts = client.run(lambda dask_worker: dask_worker.state.executing_count, workers=[victim_address])
                return cast(dict, counts)[victim_address]  # a dict: the client is synchronous

            study = pool.submit(evaluate, PARAMS, **OPTIONS, cluster=address)
            while not study.done() and not running():
                time.sleep(0.02)
            assert not study.done(), "the victim never ran a block"
            victim.kill()
            found = study.result(timeout=240)
            assert victim_address not in client.scheduler_info(n_workers=-1)["workers"]
        assert_identical(found, one_process)
    finally:
        victim.kill()
        victim.wait(30)


def test_a_scheduler_lost_mid_study_is_one_error_that_says_so(tmp_path):
    """kill -9 of the scheduler once its worker holds the study's block: a ClusterError saying the
    study was cancelled and why, not Dask's traceback (its client's log of the reconnect is quiet)."""
    scheduler, address = start_scheduler(tmp_path)
    alone = worker(address, "alone", tmp_path)
    try:
        with ThreadPoolExecutor(1) as pool:
            with Client(address, timeout=30) as client:
                client.wait_for_workers(1, timeout=120)
                study = pool.submit(evaluate, PARAMS, **LONG, cluster=address)
                while not study.done() and not any(cast(dict, client.processing()).values()):
                    time.sleep(0.02)
            scheduler.kill()
            lost = r"the study on tcp://\S+ was cancelled after 0 of 1 blocks \(scheduler-connection-lost\)"
            with pytest.raises(ClusterError, match=lost):
                study.result(timeout=120)
    finally:
        for process in (alone, scheduler):
            process.kill()
            process.wait(30)


def test_the_sweep_on_the_cluster_writes_the_one_process_table(cluster, tmp_path, capsys):
    address, _ = cluster
    args = ["--a-plus", "0.02", "0.04", "--seeds", "3", "--ticks", "3000", "--learned-after", "500"]
    assert sweep.main([*args, "--cluster", address, "--runs", str(tmp_path), "--id", "on-cluster"]) == 0
    written = json.loads((tmp_path / "on-cluster" / "table.json").read_text())
    assert written == json.loads(json.dumps(sweep.sweep([0.02, 0.04], 3, 3000, "paper", 500)))
    assert "6/6" in capsys.readouterr().err  # the progress bar counts insects


def optimise(*args: str) -> list[str]:
    """examples/optimise.py's printed lines, a short search."""
    search = ["--generations", "2", "--ticks", "3000", "--seeds", "2", "--population", "4", *args]
    done = subprocess.run(
        [sys.executable, ROOT / "examples" / "optimise.py", *search],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.splitlines()


def test_the_optimiser_on_the_cluster_makes_the_same_search(cluster):
    """CMA-ES's ask/tell loop, each generation in blocks on the cluster: the same costs, so the same
    candidates, generation by generation, and the same best."""
    address, _ = cluster
    on_cluster = optimise("--cluster", address)
    assert on_cluster == optimise()
    assert [line.split(":")[0] for line in on_cluster] == ["generation 1", "generation 2", "best"]


@pytest.fixture
def closed_port():
    """A port where nothing listens: held bound without listening, so that no process takes it."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        yield s.getsockname()[1]


def test_a_cluster_where_nothing_answers_is_one_line(closed_port, tmp_path, capsys):
    address = f"tcp://127.0.0.1:{closed_port}"
    assert sweep.main(["--seeds", "1", "--ticks", "1000", "--cluster", address, "--runs", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    # said at once, so it claims no wait
    said = f"no Dask scheduler at {address}: the connection was refused (ConnectionRefusedError)"
    assert err[-1] == f"spikinglab sweep: {said}"
    assert "Traceback" not in "\n".join(err) and not list(tmp_path.iterdir())  # no run folder left


def test_an_address_that_is_not_a_scheduler_is_named_in_one_line(cluster, tmp_path):
    """A worker's address, a port that accepts and stays silent (an HTTP server's, as the dashboard's
    is), a server that answers with other bytes, a host that does not resolve: each is one
    ClusterError that says which, where the client alone would wait without end or fail deep inside."""
    address, _ = cluster
    with Client(address, timeout=30) as client:
        a_worker = next(iter(cast(dict, client.scheduler_info())["workers"]))
    with socket.socket() as silent, socket.socket() as chatty, socket.socket() as closing:
        for server in (silent, chatty, closing):
            server.bind(("127.0.0.1", 0))
            server.listen()
            server.settimeout(30)  # the test never waits on one for good
        ports = {name: s.getsockname()[1] for name, s in (("silent", silent), ("chatty", chatty), ("closing", closing))}

        def chatter():  # answers every connection with what is not Dask's protocol
            for _ in range(2):
                connection, _ = chatty.accept()
                with connection:
                    connection.sendall(b"HTTP/1.0 200 OK\r\n\r\n" + b"\xff" * 4096)

        closed = threading.Event()
        closing.settimeout(0.1)

        def closer():  # closes every connection at once, as a tunnel with no scheduler behind it does
            while not closed.is_set():
                with contextlib.suppress(TimeoutError):
                    closing.accept()[0].close()

        with ThreadPoolExecutor(2) as threads:
            threads.submit(chatter)
            threads.submit(closer)
            cases = {
                f"tcp://127.0.0.1:{ports['closing']}": "took the connection and closed it without answering as "
                "Dask does: no Dask scheduler there (behind a tunnel or port forward, it may be down)",
                a_worker: f"{a_worker} is a Dask Worker, not a scheduler: give the scheduler's address",
                f"tcp://127.0.0.1:{ports['silent']}": "accepts connections but does not answer as Dask does within 5 s",
                f"tcp://127.0.0.1:{ports['chatty']}": "answered, but not in Dask's protocol",
                "tcp://nosuchhost.invalid:8786": "no host 'nosuchhost.invalid' (in tcp://nosuchhost.invalid:8786): "
                "the name does not resolve",
            }
            try:
                for wrong, said in cases.items():
                    with pytest.raises(ClusterError, match=re.escape(said)):
                        evaluate(PARAMS, 1000, [0], cluster=wrong)
            finally:
                closed.set()


def test_a_study_on_a_cluster_with_no_worker_says_it_waits_and_runs_once_one_comes(tmp_path, caplog):
    """A scheduler alone: the study says once that it waits for a worker, then runs on the one that
    joins, cut into blocks for it, with one process's arrays."""
    scheduler, address = start_scheduler(tmp_path)
    processes, thread = [scheduler], ThreadPoolExecutor(1)
    try:
        study = thread.submit(evaluate, PARAMS, 1000, [0], cluster=address)
        deadline = time.monotonic() + 30
        while "no worker" not in caplog.text and not study.done() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert f"no worker on the cluster at {address} yet: the study waits for one" in caplog.text
        assert not study.done()
        processes.append(worker(address, "late", tmp_path))
        on_cluster = study.result(timeout=300)
    finally:
        for p in processes[::-1]:  # the scheduler gone, a study still waiting ends: no wait on the thread for good
            stop(p)
        thread.shutdown(cancel_futures=True)
    alone = evaluate(PARAMS, 1000, [0])
    assert on_cluster.keys() == alone.keys()
    for name in alone:
        np.testing.assert_array_equal(on_cluster[name], alone[name])


def test_ctrl_c_during_the_check_of_a_silent_scheduler_ends_the_sweep_at_once(tmp_path):
    """Ctrl-C while the sweep waits for a port that accepts and stays silent to say it is a Dask
    scheduler: the sweep ends there (exit 130, nothing written), not when the 5 s check times out."""
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        silent.settimeout(60)
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        command = [sys.executable, "-m", "spikinglab", "sweep", "--cluster", address, "--runs", str(tmp_path)]
        sweep_process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            first, _ = silent.accept()  # a plain connection first, then the check's, which waits for an answer
            second, _ = silent.accept()
            with first, second:
                sweep_process.send_signal(signal.SIGINT)
                _, err = sweep_process.communicate(timeout=4)  # the check alone would hold it 5 s
        finally:
            sweep_process.kill()
    assert sweep_process.returncode == 130
    assert err.strip().splitlines()[-1] == "spikinglab sweep: interrupted, no table written"
    assert "Traceback" not in err and not list(tmp_path.iterdir())


def test_a_malformed_address_is_refused_before_anything_starts(tmp_path, capsys):
    with pytest.raises(SystemExit) as ended:
        sweep.main(["--cluster", "127.0.0.1:8786", "--runs", str(tmp_path)])
    assert ended.value.code == 2
    assert "argument --cluster: expected a Dask scheduler's address tcp://HOST:PORT, got '127.0.0.1:8786'" in (
        capsys.readouterr().err
    )
    for wrong in ("scheduler", 8786):
        with pytest.raises(ValueError, match=f"tcp://HOST:PORT, got {wrong!r}"):
            evaluate(PARAMS, 1000, [0], cluster=wrong)  # type: ignore[arg-type]
