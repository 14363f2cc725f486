"""A supervised service ends with its supervisor, even when the supervisor dies by SIGKILL.

The supervisor starts every child in its own process group (so a signal to one service never
reaches another), which also means a killed ``launch``, ``demo`` or ``bench`` would leave its
services running. Each child therefore asks Linux for SIGTERM when its parent ends
(``PR_SET_PDEATHSIG``): it stops the way Ctrl-C stops it, and the recorder closes its file.
The supervisor spawns from one long-lived thread, the one the signal is tied to.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys

#: set by the supervisor to its own pid in every child's environment.
SUPERVISOR_ENV = "STEREOVOX_SUPERVISOR_PID"
_PR_SET_PDEATHSIG = 1


def follow_supervisor() -> None:
    """Arrange SIGTERM for this process when the supervisor that started it ends (Linux only)."""
    supervisor = os.environ.get(SUPERVISOR_ENV)
    if not supervisor or not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    if os.getppid() != int(supervisor):  # it died before the request was in place
        os.kill(os.getpid(), signal.SIGTERM)
