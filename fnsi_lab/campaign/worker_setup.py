"""Dask worker preload of ``fnsi-lab batch``'s local cluster: Ctrl-C belongs to the command.

A terminal's Ctrl-C reaches every process of the foreground group, the local cluster's
worker processes too; each then died with a KeyboardInterrupt traceback and its nanny logged
CommClosedError/CancelledError ones while ``batch`` itself was finishing cleanly (exit 130).
The workers ignore SIGINT; the command stops them through the cluster when it is
interrupted (``fnsi_lab.campaign.batch.dask_client``).
"""

from __future__ import annotations

import signal
import threading
from typing import Any


def dask_setup(worker: Any = None) -> None:
    """Called by Dask in each worker process as it starts: ignore SIGINT there."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
