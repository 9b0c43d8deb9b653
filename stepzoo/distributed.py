"""Tasks on a Dask cluster, shared by the sweep and the planner: connect to a scheduler (or
start a LocalCluster here) and run a batch with retries. Dask is imported only when a
scheduler is asked for: the core runs without it."""
from __future__ import annotations

import contextlib
import logging

from stepzoo.errors import UsageError

CONNECT_TIMEOUT_S = 10.0      # [s] a scheduler silent this long is reported, not waited for
# Re-runs of a task that raised on a worker. A task whose worker died is re-run by the
# scheduler itself (up to distributed.scheduler.allowed-failures times, 3 by default).
RETRIES = 2
FIX = ("start one with `dask scheduler` and give its tcp://HOST:8786, or use local:N for N "
       "worker processes on this machine")


@contextlib.contextmanager
def connect(address: str):
    """A Dask client of the scheduler at `address` ('tcp://host:8786'), or of a LocalCluster
    of N single-threaded worker processes on loopback for 'local:N'; closed on exit."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise UsageError("--scheduler needs Dask, which is not installed; "
                         "pip install 'stepzoo[distributed]'") from None
    if address.startswith("local:"):
        n = address.removeprefix("local:")
        if not n.isdigit() or int(n) < 1:
            raise UsageError(f"--scheduler {address}: local:N needs a worker count N >= 1, "
                             "such as local:2")
        # Processes of one thread: a chunk's Python parts hold the GIL, so threads of one
        # worker would take turns; Dask's nanny already pins OMP/MKL/OpenBLAS to one thread.
        with LocalCluster(n_workers=int(n), threads_per_worker=1, processes=True,
                          host="127.0.0.1", dashboard_address=None,
                          silence_logs=logging.ERROR) as cluster, \
                Client(cluster) as client:
            yield client
        return
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError, TypeError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise UsageError(f"no Dask scheduler answers at {address} ({first}); {FIX}") from None
    with client:
        yield client


def gather_in_order(client, fn, items, *args) -> list:
    """[fn(item, *args) for item in items], one task per item on the client's cluster."""
    return client.gather([client.submit(fn, item, *args, retries=RETRIES, pure=False)
                          for item in items])
