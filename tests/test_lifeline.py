"""A supervised service ends with its supervisor, even when its own shutdown hangs (common/lifeline.py)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO, wait_for

from common.lifeline import SUPERVISOR_ENV

# the service: follows its supervisor, but ignores SIGTERM, as a shutdown stuck in a library would
SERVICE = """
import signal, sys, time
from common.lifeline import follow_supervisor
signal.signal(signal.SIGTERM, signal.SIG_IGN)
follow_supervisor(grace_s=1.0)
print("ready", flush=True)
time.sleep(600)
"""

# the supervisor: starts the service in a session of its own and reports its pid
SUPERVISOR = f"""
import os, subprocess, sys, time
env = dict(os.environ, {SUPERVISOR_ENV}=str(os.getpid()))
child = subprocess.Popen([sys.executable, "-c", {SERVICE!r}], env=env, start_new_session=True)
print(child.pid, flush=True)
time.sleep(600)
"""


def ended(pid: int) -> bool:
    """Gone, or a zombie nobody reaps (an orphan in a container whose init does not)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return True
    return "\nState:\tZ" in status


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG and /proc are Linux's")
@pytest.mark.timeout(60)
def test_a_service_whose_shutdown_hangs_still_ends_with_its_killed_supervisor() -> None:
    supervisor = subprocess.Popen([sys.executable, "-c", SUPERVISOR], cwd=REPO, stdout=subprocess.PIPE,
                                  env=dict(os.environ, PYTHONPATH=str(REPO)), start_new_session=True)
    assert supervisor.stdout is not None
    service = int(supervisor.stdout.readline())
    try:
        assert supervisor.stdout.readline().strip() == b"ready"  # the service shares the pipe
        os.killpg(supervisor.pid, signal.SIGKILL)
        supervisor.wait(10)
        # the watch thread sends SIGTERM (ignored here), then ends the process 1 s later
        wait_for(lambda: ended(service), 20, "the service to end after its supervisor was killed")
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(supervisor.pid, signal.SIGKILL)
        with contextlib.suppress(ProcessLookupError):
            os.kill(service, signal.SIGKILL)
