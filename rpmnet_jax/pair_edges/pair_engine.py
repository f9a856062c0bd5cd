"""The work of :func:`rpmnet_jax.align_scans` on scans and pairs as tasks: in this process, or on a Dask cluster
(an embedded ``LocalCluster`` of worker processes, or a running scheduler). The scans are prepared there
(:meth:`PairEngine.prepare`), the pair registrations run there, each result kept in a
:class:`~rpmnet_jax.pair_edges.pair_cache.PairCache` when one is given, and so does other work on many pairs
(:meth:`PairEngine.map_pairs`: the joint refinement's normal equations and final measurements).

Tasks are pure functions of the scans, the pairs, the settings and the seed: a pair's random sample comes
from its own generator, seeded by ``(seed, stage, i, j)``, so its edge does not depend on which worker ran it,
in what order, or whether it ran again after a worker died. Network edges run in fixed chunks of
``batch_size`` pairs (one batched network call each; a chunk's composition depends only on the pair list),
refinement edges one pair a task. A scan prepared on the cluster stays on the worker that made it (made again
from its cloud, which the scheduler keeps, if that worker dies); the network's parameters and scans passed in
ready-made go to the cluster once, as tasks that unpickle them; a worker fetches those its tasks need and compiles
the network once per process (through JAX's persistent compilation cache when this process has one). Results
are collected as they finish; the pose graph stays with the caller.

Faults: a worker that dies mid-run loses only its running tasks and the results not yet fetched from it; the
scheduler runs them again on the other workers, and as the edges do not depend on where they ran, the poses are the
same. A task that kills every worker running it stops the run with one line naming its scan or pairs
(:class:`PairTaskError`); a scheduler left with no worker for :data:`NO_WORKERS_TIMEOUT` seconds stops it with one
line too (:class:`NoWorkersError`), and so does a scheduler that stops answering, the cache keeping what finished.
Every worker's tasks size Numba's, BLAS's and XLA's thread pools to the worker's threads (:func:`_size_pools`;
an embedded cluster's workers also get :func:`worker_environment` as they start): one worker a core, not every
pool on every core.
"""

from __future__ import annotations

import collections
import concurrent.futures
import os
import pickle
import time
from typing import NamedTuple

import numpy as np

from rpmnet_jax.classical import icp
from rpmnet_jax.geometry import threads
from rpmnet_jax.pair_edges import edges as edges_lib, pair_cache

CONNECT_TIMEOUT = "20s"  # waiting for a scheduler that does not answer
NO_WORKERS_TIMEOUT = 60.0  # seconds a scheduler may have no worker before a run stops (NoWorkersError)
WORKERS_POLL = 1.0  # seconds between asking the scheduler for its workers while no result comes
RESULT_TIMEOUT = 10.0  # seconds to fetch a finished result; past it (its worker died) it is awaited again
THREADS_PER_WORKER = 1  # an embedded cluster's worker: one task at a time, every pool it uses this size
NETWORK_TAG, CLASSICAL_TAG = 0, 1  # a pair's generator: (seed, tag, i, j); refinement round r: (seed, 2 + r, i, j)
STARTED = "rpmnet_jax-pair-task-started"  # the scheduler's event topic of pair tasks starting on workers
_sized = []  # this process's pools sized to its worker's threads (_size_pools)
_PARAMS = object()  # stands for the network's parameters among a task's arguments (sent once, not per task)


class Settings(NamedTuple):
    """What decides a pair's edge besides the two scans (caller's units)."""

    max_distance: float  # correspondence distance
    num_points: int  # network samples per scan
    num_iters: int  # network iterations
    batch_size: int  # pairs per network call (a chunk)
    network_icp_points: int  # source points of the short ICP after the network
    refine_points: int  # source points of a refinement edge's ICP
    seed: int
    ransac_distance: float = 0.0  # classical edges: RANSAC's inlier distance
    max_plane_residual: float = 0.1  # classical edges: a hypothesis is good below this × max_distance
    identity_start: bool = True  # classical edges: ICP from the scans as they lie too (not for scans in their
    # sensors' frames: there it is the sensor standing still, and a LiDAR sweep's rings lock onto it)


def pair_rng(seed: int, tag: int, i: int, j: int) -> np.random.Generator:
    """The generator of pair ``(i, j)`` in stage ``tag``: the same wherever and whenever the pair runs."""
    return np.random.default_rng([int(seed), int(tag), int(i), int(j)])


def network_chunk(scans, chunk, todo, params, cfg, settings: Settings, compile_cache=None, tick=None) -> list:
    """Network answers for the pairs ``chunk [(i, j), ...]`` in one batched call (a pair may repeat: padding),
    then the short ICP of those in ``todo``: ``[((i, j), [edge]), ...]`` in chunk order (``tick()`` after
    each)."""
    _use_compile_cache(compile_cache)
    s = settings
    starts = edges_lib.network_starts(params, scans, chunk, cfg=cfg, num_points=s.num_points,
                                      num_iters=s.num_iters, batch_size=len(chunk), seed=s.seed)
    out = []
    for (i, j), start in dict(zip(chunk, starts)).items():
        if (i, j) in todo:
            out.append(((i, j), [edges_lib.icp_edge(scans, i, j, start, s.max_distance,
                                                    pair_rng(s.seed, NETWORK_TAG, i, j), num_points=s.network_icp_points,
                                                    schedule=icp.NETWORK_EDGE, stage="network")]))
            if tick is not None:
                tick()
    return out


@threads.compiled_loops()  # on a worker too: BLAS leaves the cores to the compiled loops
def classical_pair(scans, i, j, settings: Settings) -> list:
    """``[((i, j), edges)]``: the answers of scan ``i`` onto scan ``j`` from FPFH + RANSAC
    (:func:`~rpmnet_jax.pair_edges.edges.classical_edges`)."""
    s = settings
    return [((i, j), edges_lib.classical_edges(scans, i, j, s.max_distance, s.ransac_distance,
                                               pair_rng(s.seed, CLASSICAL_TAG, i, j), num_points=s.network_icp_points,
                                               max_plane_residual=s.max_plane_residual, identity=s.identity_start))]


@threads.compiled_loops()  # on a worker too: BLAS leaves the cores to the compiled loops
def refine_pair(scans, i, j, start, round_, settings: Settings) -> list:
    """``[((i, j), [edge])]``: ICP of scan ``i`` onto scan ``j`` from ``start (4, 4)`` (refinement round
    ``round_``)."""
    s = settings
    return [((i, j), [edges_lib.icp_edge(scans, i, j, start, s.max_distance, pair_rng(s.seed, 2 + round_, i, j),
                                         num_points=s.refine_points, schedule=icp.REFINE_EDGE)])]


def _share(fn, scans, chunk, args):
    """A task of :meth:`PairEngine.map_pairs`: ``fn(scans, chunk, *args)``."""
    return fn(scans, chunk, *args)


def _use_compile_cache(folder) -> None:
    """In a worker: JAX's persistent compilation cache in ``folder``, unless the worker has its own (or none
    can be made there)."""
    if not folder:
        return
    import jax

    if jax.config.jax_compilation_cache_dir:
        return
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError:
        return
    jax.config.update("jax_compilation_cache_dir", folder)


def _logged(fn, *args, **kwargs):
    """Runs the task ``fn(*args, **kwargs)`` on a Dask worker, first telling the scheduler that it starts
    (an event of topic :data:`STARTED`: the task's key), so a task that kills its workers can be told from the
    tasks queued beside it (:meth:`PairEngine._killer`)."""
    import distributed

    worker = distributed.get_worker()
    worker.log_event(STARTED, worker.get_current_task())
    _size_pools(worker.state.nthreads)
    return fn(*args, **kwargs)


def _size_pools(nthreads: int) -> None:
    """In a worker's task, before it runs: the pools its code uses sized to the worker's ``nthreads``, however the
    worker was started (``dask worker``, ``dask ssh``, a job queue, Kubernetes: no environment needed). XLA's CPU
    pool (``PJRT_NPROC``, unless set: read when JAX starts its backend, so before the first network task) and BLAS
    (threadpoolctl) once per process; Numba's in this task's thread (``numba.set_num_threads`` holds per thread).
    Where :func:`worker_environment` applied, this changes nothing."""
    import numba

    if not _sized:
        from threadpoolctl import threadpool_limits

        os.environ.setdefault("PJRT_NPROC", str(nthreads))
        threadpool_limits(limits=nthreads, user_api="blas")  # not as a context: it stays
        _sized.append(nthreads)
    numba.set_num_threads(min(nthreads, numba.config.NUMBA_NUM_THREADS))


def worker_environment(nthreads: int) -> dict:
    """Environment variables that size a worker process's thread pools to its ``nthreads``: Numba's (read when
    Numba is imported), BLAS's (OpenBLAS, MKL, OpenMP: read when a library loads) and XLA's CPU pool
    (``PJRT_NPROC``: read when JAX first runs). An embedded cluster's workers get them as they start; any other
    worker's tasks size the pools themselves (:func:`_size_pools`)."""
    n = str(int(nthreads))
    return {name: n for name in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                 "PJRT_NPROC")}


def dask_setup(worker) -> None:
    """Run by Dask in each worker of an embedded cluster as it starts (this module is its preload): the BLAS
    libraries loaded before :func:`worker_environment` applied (NumPy's: Dask imports it first) limited to the
    worker's threads too."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=worker.state.nthreads, user_api="blas")  # not as a context: it stays


def check_scheduler(scheduler):
    """``scheduler`` if usable: ``None`` (this process), ``"local"`` or a worker count ``n ≥ 1`` (an embedded
    ``LocalCluster``), a scheduler address ``"tcp://HOST:PORT"`` (any ``scheme://``), or a
    ``distributed.Client``; else ``ValueError``."""
    if scheduler is None or hasattr(scheduler, "submit"):
        return scheduler
    if isinstance(scheduler, str) and scheduler.strip().isdigit():
        scheduler = int(scheduler)
    if isinstance(scheduler, (int, np.integer)) and not isinstance(scheduler, bool):
        if scheduler < 1:
            raise ValueError(f"scheduler: a local cluster needs at least 1 worker, got {scheduler}")
        return int(scheduler)
    if scheduler == "local" or (isinstance(scheduler, str) and "://" in scheduler
                                and scheduler.split("://", 1)[1].strip()):
        return scheduler
    raise ValueError(f"scheduler must be None, 'local', a worker count or an address like tcp://HOST:8786, "
                     f"got {scheduler!r}")


class PairTaskError(RuntimeError):
    """A task that the Dask scheduler gave up on (it killed every worker that ran it; the message names its scan
    or pairs), or a scheduler that stopped answering; the message is one line."""


class NoWorkersError(PairTaskError):
    """The Dask scheduler has had no worker for :data:`NO_WORKERS_TIMEOUT` seconds while pair tasks wait; the
    message, one line, says what the cache kept."""


class PairEngine:
    """Runs pair tasks on ``scheduler`` (see :func:`check_scheduler`), keeping results in ``cache`` (a folder or
    a :class:`~rpmnet_jax.pair_edges.pair_cache.PairCache`; ``None``: none). A context manager: leaving it
    closes the cluster it started or the connection it made."""

    def __init__(self, scheduler=None, cache=None):
        self.scheduler = check_scheduler(scheduler)
        self.cache = cache if cache is None or isinstance(cache, pair_cache.PairCache) else pair_cache.PairCache(cache)
        self.client = self._cluster = self._scan_futures = self._params_future = self._prepared = None
        self._own_client = False

    def __enter__(self):
        if self.scheduler is None:
            return self
        import distributed  # a dependency; imported only when a scheduler is asked for
        if hasattr(self.scheduler, "submit"):
            self.client = self.scheduler
            return self
        self._own_client = True
        if isinstance(self.scheduler, int) or self.scheduler == "local":
            workers = self.scheduler if isinstance(self.scheduler, int) else None
            self._cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=THREADS_PER_WORKER,
                                                     processes=True, dashboard_address=None, preload=[__name__],
                                                     env=worker_environment(THREADS_PER_WORKER))
            self.client = distributed.Client(self._cluster)
            return self
        try:
            self.client = distributed.Client(self.scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError) as e:
            raise ValueError(f"no Dask scheduler answers at {self.scheduler} ({type(e).__name__})") from e
        return self

    def __exit__(self, *exc):
        if self._own_client and self.client is not None:
            self.client.close()
        if self._cluster is not None:
            self._cluster.close()
        self.client = self._cluster = self._scan_futures = self._params_future = self._prepared = None

    def bind(self, scans, params, cfg, settings: Settings) -> None:
        """The scans (:class:`~rpmnet_jax.pair_edges.edges.Scan`), network (``params``; ``None``: the shipped
        model, loaded when the network first runs) and settings of the coming tasks; the scans are sent to the
        cluster here, once (the network's parameters when it first runs: :meth:`_send`)."""
        self.scans, self.params, self.cfg, self.settings = scans, params, cfg, settings
        self._digests = [pair_cache.scan_digest(s) for s in scans] if self.cache is not None else None
        self._params_digest = None
        if self.client is not None and scans is not self._prepared:  # scans prepared here are there already
            self._scan_futures = self._send(list(scans))

    def release(self) -> None:
        """Lets the bound scans go, here and on the cluster, until the next :meth:`bind`."""
        self.scans = self._scan_futures = self._prepared = self._digests = None

    def prepare(self, fn, jobs, tick=None) -> list:
        """``[fn(*job) for job in jobs]``: the scans (:class:`~rpmnet_jax.pair_edges.edges.Scan`) made ready for
        pairing, one task a scan; ``tick(done, total)`` as they finish. On a cluster each stays on its worker for
        the pair tasks (a list :meth:`bind` then sends nowhere again; made again from its job, which the scheduler
        keeps, if its worker dies) and comes here too."""
        if self.client is None:
            scans = []
            for job in jobs:
                scans.append(fn(*job))
                if tick is not None:
                    tick(len(scans), len(jobs))
            return scans
        import uuid

        import dask

        run = uuid.uuid4().hex  # keys by index: hashing every raw cloud would cost the caller its time
        with dask.config.set({"distributed.admin.large-graph-warning-threshold": "64GB"}):  # the clouds: meant
            submitted = [(self._submit(fn, *job, key=f"{fn.__name__}-{k}-{run}"), f"scan {k}")
                         for k, job in enumerate(jobs)]
        scans = self._in_order(submitted, "scans still to prepare", "no scan was kept", tick)
        self._scan_futures, self._prepared = [future for future, _ in submitted], scans
        return scans

    def map_pairs(self, fn, chunks, *args) -> list:
        """``[fn(scans, chunk, *args) for chunk in chunks]`` (``chunks``: lists of pairs ``(i, j)``) with the bound
        scans, in this process or a task a chunk on the cluster (there ``scans`` holds only the chunk's, by index):
        work on many pairs that needs no cache (a joint refinement's normal equations, the final measurements)."""
        if self.client is None:
            return [fn(self.scans, chunk, *args) for chunk in chunks]
        import dask.base

        shared = self._send([args])[0]  # once, not with every task
        submitted = []
        for chunk in chunks:
            scans = {s: self._scan_futures[s] for s in sorted({s for p in chunk for s in p})}
            key = f"{fn.__name__}-{dask.base.tokenize(fn, scans, chunk, shared)}"
            label = f"{fn.__name__} on {len(chunk)} pairs from {tuple(chunk[0])}"
            submitted.append((self._submit(_share, fn, scans, chunk, shared, key=key), label))
        return self._in_order(submitted, f"tasks of {fn.__name__} still to run", "none of its results is kept")

    def _in_order(self, submitted, what: str, kept: str, tick=None) -> list:
        """The results of ``submitted [(future, label), ...]`` (distinct keys) in that order, ``tick(done, total)``
        as they finish; ``what`` is left when a run stops ("scans still to prepare"), ``kept`` what a task that
        kills its workers leaves."""
        position = {future.key: k for k, (future, _) in enumerate(submitted)}
        out, done = [None] * len(submitted), [0]
        for future, value in self._gather(submitted, lambda: f"{len(submitted) - done[0]} of {len(submitted)} {what}",
                                          kept):
            out[position[future.key]] = value
            done[0] += 1
            if tick is not None:
                tick(done[0], len(submitted))
        return out

    def _bind_network(self) -> None:
        """Loads the shipped model if no parameters were given, digests them for the cache, sends them to the
        workers; once."""
        if self.params is None:
            from rpmnet_jax.weights import loading

            self.params = loading.load_params(None)
        if self.cache is not None and self._params_digest is None:
            self._params_digest = pair_cache.params_digest(self.params)
        if self.client is not None and self._params_future is None:
            import jax

            self._params_future = self._send([jax.tree.map(np.asarray, self.params)])[0]
            self._compile_cache = jax.config.jax_compilation_cache_dir or None

    def _send(self, values: list) -> list:
        """Futures of ``values``: tasks that unpickle them, their bytes kept by the scheduler, so that a copy lost
        with its worker is made again elsewhere. Scattered data is not: the scheduler's memory manager drops the
        replicas a broadcast made, and a worker that died with a scan's only copy stopped the run."""
        import dask

        with dask.config.set({"distributed.admin.large-graph-warning-threshold": "64GB"}):  # meant to be there
            return [self.client.submit(pickle.loads, pickle.dumps(v, protocol=5), pure=False) for v in values]

    def network_edges(self, pairs, tick=None) -> list:
        """Network edges (network + short ICP) of ``pairs [(i, j), ...]``, one per pair, in that order;
        ``tick(done, total)`` as they finish."""
        self._bind_network()
        s = self.settings
        key = (self._params_digest, repr(self.cfg), s.num_points, s.num_iters, s.batch_size, s.network_icp_points,
               icp.NETWORK_EDGE, s.max_distance, s.seed)
        names = {p: self._name("network", p, key) for p in pairs}
        found = self._load(names)
        tasks = []
        for chunk, padded in edges_lib.batches([tuple(p) for p in pairs], s.batch_size):
            todo = [p for p in chunk if p not in found]
            if todo:
                tasks.append((network_chunk, (padded, todo, _PARAMS, self.cfg, s), chunk))
        return [answers[0] for answers in self._run(tasks, names, found, pairs, tick)]

    def classical_edges(self, pairs, tick=None) -> list:
        """Classical edges (FPFH + RANSAC + short ICP) of ``pairs [(i, j), ...]``: per pair, in that order, the
        list of its distinct answers (possibly empty); ``tick(done, total)`` as they finish."""
        s = self.settings
        key = (edges_lib.FEATURE_POINTS, edges_lib.KEYPOINT_VOXELS, edges_lib.FEATURE_NEIGHBOURS,
               s.network_icp_points, icp.NETWORK_EDGE, s.max_distance, s.ransac_distance, s.max_plane_residual, s.seed,
               s.identity_start)
        names = {tuple(p): self._name("classical", p, key) for p in pairs}
        found = self._load(names)
        tasks = [(classical_pair, (i, j, s), [(i, j)]) for i, j in names if (i, j) not in found]
        return self._run(tasks, names, found, list(names), tick)

    def refine_edges(self, pairs, starts, round_: int, tick=None) -> list:
        """ICP edges of ``pairs [(i, j), ...]`` from ``starts (P, 4, 4)`` in refinement round ``round_``."""
        s = self.settings
        starts = {tuple(p): np.asarray(t, np.float64) for p, t in zip(pairs, starts)}
        names = {p: self._name(f"refine{round_}", p, (s.refine_points, icp.REFINE_EDGE, s.max_distance, s.seed,
                                                      starts[p])) for p in starts}
        found = self._load(names)
        tasks = [(refine_pair, (i, j, starts[(i, j)], round_, s), [(i, j)])
                 for i, j in starts if (i, j) not in found]
        return [answers[0] for answers in self._run(tasks, names, found, list(starts), tick)]

    def _name(self, stage, pair, key):
        if self.cache is None:
            return None
        i, j = pair
        return pair_cache.edge_name(stage, i, j, self._digests[i], self._digests[j], *key)

    def _load(self, names) -> dict:
        if self.cache is None:
            return {}
        found = {p: self.cache.load(n) for p, n in names.items()}
        return {p: e for p, e in found.items() if e is not None}

    def _run(self, tasks, names, found, pairs, tick) -> list:
        """Runs ``tasks [(fn, args, the pairs whose scans it needs)]`` (each returns ``[((i, j), [edge, ...]),
        ...]``); stores each new pair's edges; returns the edge lists of ``pairs`` in order."""
        done, total = [len(found)], len(pairs)
        edges = dict(found)

        def finished(new):
            for pair, answers in new:
                edges[pair] = answers
                if self.cache is not None:
                    self.cache.store(names[pair], answers)

        def advance(n=1):
            done[0] += n
            if tick is not None:
                tick(done[0], total)

        if found and tick is not None:
            tick(done[0], total)
        if self.client is None:
            for fn, args, _ in tasks:
                args = tuple(self.params if a is _PARAMS else a for a in args)
                if fn is network_chunk:
                    finished(fn(self.scans, *args, tick=advance))
                else:
                    finished(fn(self.scans, *args))
                    advance()
        else:
            submitted = []
            for fn, args, needs in tasks:
                scans = {s: self._scan_futures[s] for s in sorted({s for p in needs for s in p})}
                args = tuple(self._params_future if a is _PARAMS else a for a in args)
                extra = {"compile_cache": self._compile_cache} if fn is network_chunk else {}
                submitted.append((self._submit(fn, scans, *args, **extra), f"pairs {[tuple(p) for p in needs]}"))
            for _, new in self._gather(submitted, lambda: f"{total - done[0]} of {total} pairs of this stage still to "
                                                          "run"):
                finished(new)
                advance(len(new))
        return [edges[tuple(p)] for p in pairs]

    def _submit(self, fn, *args, key=None, **kwargs):
        """The future of the task ``fn(*args, **kwargs)`` on the cluster, started through :func:`_logged`; ``key``
        by default named as its function and determined by its arguments."""
        import dask.base

        key = key or f"{fn.__name__}-{dask.base.tokenize(fn, *args, **kwargs)}"
        return self.client.submit(_logged, fn, *args, key=key, **kwargs)

    def _gather(self, submitted, left, kept="the pairs finished before it are in the cache (if any)"):
        """Yields ``(future, result)`` of ``submitted [(future, label), ...]`` as they finish (a result lost with
        its worker is awaited again: the scheduler runs the task elsewhere). Stops with one line: a task the
        scheduler gave up on (:class:`PairTaskError` naming its label), no worker for :data:`NO_WORKERS_TIMEOUT`
        seconds (:class:`NoWorkersError`), a scheduler that stopped answering; ``left()`` says what was left to
        run ("3 of 10 pairs of this stage still to run"); ``kept`` what a task that kills its workers leaves."""
        import distributed

        labels = {future.key: label for future, label in submitted}
        unfinished = set(labels)
        results, workers = distributed.as_completed([future for future, _ in submitted]), _Workers(self.client)
        while not results.is_empty():
            batch = results.next_batch(block=False)
            if not batch:  # none finished: is there still a worker to run them?
                if workers.gone_for() >= NO_WORKERS_TIMEOUT:
                    raise NoWorkersError(self._no_workers(left()))
                time.sleep(0.02)  # as_completed's own wait polls every 0.1 s
            for future in batch:
                if workers.gone_for() >= NO_WORKERS_TIMEOUT:  # each lost result costs RESULT_TIMEOUT: not all of them
                    raise NoWorkersError(self._no_workers(left()))
                try:
                    value = future.result(timeout=RESULT_TIMEOUT)
                except distributed.KilledWorker as e:  # the scheduler gave up on it: name the task, one line
                    raise PairTaskError(self._killer(future.key, labels, unfinished, kept)) from e
                except distributed.TimeoutError:  # its result died with its worker: it runs again elsewhere
                    results.add(future)
                    continue
                except concurrent.futures.CancelledError as e:  # the client cancels every task when it loses the
                    # scheduler (and gives up reconnecting after CONNECT_TIMEOUT)
                    raise PairTaskError(f"the Dask scheduler at {self.client.scheduler.address} stopped answering "
                                        f"with {left()}; {self._kept('the scheduler is back')}") from e
                unfinished.discard(future.key)
                yield future, value

    def _killer(self, key, labels: dict, unfinished: set, kept: str) -> str:
        """The one line of a run stopped by a task that killed its workers. The scheduler gives up on every task
        that was on a worker as it died too often, those queued there beside the killer as well: the killer is the
        unfinished task that started most often (:func:`_logged`); ``key`` (the task given up on) when none did.
        ``labels``: what each task's key works on ("pairs [(0, 1)]"); ``kept``: what the run leaves."""
        starts = collections.Counter(key for _, key in self.client.get_events(STARTED))
        killer = max(unfinished, key=lambda k: starts[k], default=key)
        killer = killer if starts[killer] >= 2 else key
        count = f" {starts[killer]} times" if starts[killer] >= 2 else ""
        return f"the task of {labels[killer]} killed the Dask workers that ran it{count}; {kept}"

    def _no_workers(self, left: str) -> str:
        """The one line of a run stopped for want of workers, with ``left`` still to run."""
        return (f"no Dask workers at {self.client.scheduler.address} for {NO_WORKERS_TIMEOUT:g} s, {left}; "
                f"{self._kept('workers are there')}")

    def _kept(self, when: str) -> str:
        """What a stopped run leaves for the next one, which can start ``when``."""
        return (f"the cache keeps the pairs that finished: the same command resumes from them once {when}"
                if self.cache is not None else "no cache was given, so none of the finished pairs is kept")


class _Workers:
    """How long a Dask scheduler has had no worker (asked at most every :data:`WORKERS_POLL` seconds; a scheduler
    that does not answer has none)."""

    def __init__(self, client):
        self.client, self.asked, self.none_since = client, -float("inf"), None

    def gone_for(self) -> float:
        """Seconds since the scheduler was first seen without a worker (``0``: it has some)."""
        import distributed

        now = time.monotonic()
        if now - self.asked >= WORKERS_POLL:
            self.asked = now
            try:
                count = len(self.client.nthreads(callback_timeout=WORKERS_POLL * 5))
            except (OSError, distributed.TimeoutError):
                count = 0
            self.none_since = None if count else (now if self.none_since is None else self.none_since)
        return 0.0 if self.none_since is None else now - self.none_since
