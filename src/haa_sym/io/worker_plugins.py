"""Plugins for the dask workers of ``--scheduler local:N`` (imported only when such a cluster
starts: distributed is not imported by the rest of the package)."""
from __future__ import annotations

from distributed import WorkerPlugin


class OneBlasThread(WorkerPlugin):
    """A dask worker plugin: BLAS on one thread in the worker's process.

    A worker of ``local:N`` is one thread of one process (:func:`haa_sym.io.tasks.cluster`), but a *forked*
    worker (:data:`haa_sym.io.tasks.LOCAL_START_METHOD`) inherits the command's OpenBLAS initialised with a thread
    per core: dask's ``OMP_NUM_THREADS=1`` (its nanny's pre-spawn environment) is read by
    OpenBLAS only when it loads (measured: each forked worker of local:2 had 2 OpenBLAS threads
    on this 2-core machine, four BLAS threads on two cores; local:1's one worker could use both
    cores in its matrix products, which a one-worker baseline must not). Registered with
    ``Client.register_plugin``, so that a worker started later (a nanny's restart) gets it too.
    """

    idempotent = True

    def setup(self, worker=None):
        from threadpoolctl import threadpool_limits
        # kept for the process's life: the returned limiter is not used as a context manager
        self._limits = threadpool_limits(limits=1, user_api="blas")

