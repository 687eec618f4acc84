"""What every LocalCluster worker does when it starts (a Dask worker plugin).

Imported only where a LocalCluster is started: it needs ``distributed``.
"""

from __future__ import annotations

from typing import Any

from distributed import WorkerPlugin

from cablesvc.threads import one_blas_thread

__all__ = ["OneBlasThread"]


class OneBlasThread(WorkerPlugin):
    """:func:`cablesvc.threads.one_blas_thread` on every worker, a restarted one too."""

    name = "cablesvc-one-blas-thread"

    def setup(self, worker: Any) -> None:
        one_blas_thread()
