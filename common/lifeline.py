"""A supervised service ends with its supervisor, even when the supervisor dies by SIGKILL.

The supervisor starts every child in its own process group (so a signal to one service never
reaches another), which also means a killed ``launch``, ``demo`` or ``bench`` would leave its
services running. Each child therefore asks Linux for SIGTERM when its parent ends
(``PR_SET_PDEATHSIG``): it stops the way Ctrl-C stops it, and the recorder closes its file.
The supervisor spawns from one long-lived thread, the one the signal is tied to.

A thread of the service also watches its parent. Once the supervisor is gone, it sends the same
SIGTERM, and if the service has still not ended ``grace_s`` later, it ends the process outright.
A shutdown that hangs would otherwise outlive everything: a test suite once left a router
running for 14 minutes after its launcher was killed.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time

#: set by the supervisor to its own pid in every child's environment.
SUPERVISOR_ENV = "STEREOVOX_SUPERVISOR_PID"
_PR_SET_PDEATHSIG = 1
#: how often the watch thread looks at the parent (s).
_WATCH_S = 0.5


def follow_supervisor(grace_s: float = 10.0) -> None:
    """Arrange SIGTERM for this process when the supervisor that started it ends (Linux only)."""
    supervisor = os.environ.get(SUPERVISOR_ENV)
    if not supervisor or not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    threading.Thread(target=_watch, args=(int(supervisor), grace_s), name="lifeline", daemon=True).start()


def _watch(supervisor: int, grace_s: float) -> None:
    """SIGTERM once the supervisor is gone; the end of the process if that has not ended it in time."""
    while os.getppid() == supervisor:
        time.sleep(_WATCH_S)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(grace_s)
    os._exit(1)
