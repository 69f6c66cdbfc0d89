"""Imported only by multiprocessing's fork server of ``fnsi-lab batch``: ignore SIGINT.

``multiprocessing.set_forkserver_preload`` makes the fork server import this module before
it serves; the fork server restores, in every process it forks, the SIGINT disposition it
had before serving: ignored. So the local cluster's worker processes ignore a terminal's
Ctrl-C from their first instruction (no traceback from a worker interrupted half-way
through its start-up) while the command itself still gets it and closes the cluster
(``fnsi_lab.campaign.batch.dask_client``). Importing it anywhere else would make that
process ignore Ctrl-C: nothing else imports it.
"""

import signal
import threading

if threading.current_thread() is threading.main_thread():
    signal.signal(signal.SIGINT, signal.SIG_IGN)
