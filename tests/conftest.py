"""Shared test helpers: free ports, process groups that always die, and the shared data folder."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("STEREOVOX_SHARED", REPO.parent / "shared"))


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nobody listens on right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def shared_path(*parts: str) -> Path:
    """A path inside ../shared; skips where it is absent, but fails under CI (CI=true)."""
    path = SHARED.joinpath(*parts)
    if not path.exists():
        reason = f"{path} is missing (../shared not beside the checkout)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(reason)
        pytest.skip(reason)
    return path


def load_script(name: str) -> ModuleType:
    """A file of scripts/ as a module, for tests of its functions (scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # a dataclass looks its module up there
    spec.loader.exec_module(module)
    return module


def stereovox_cmd(*args: str) -> list[str]:
    """The CLI run with this interpreter, so tests use the checkout under test."""
    return [sys.executable, "-m", "services.cli", *args]


class Processes:
    """Starts processes in their own process groups and kills every group at teardown."""

    def __init__(self, log_dir: Path) -> None:
        self.procs: list[subprocess.Popen[bytes]] = []
        self.log_dir = log_dir

    def start(self, cmd: list[str], name: str, env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
        log = open(self.log_dir / f"{name}.log", "wb")  # noqa: SIM115 - owned by the process
        full_env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        proc = subprocess.Popen(
            cmd, stdout=log, stderr=subprocess.STDOUT, cwd=REPO, env=full_env, start_new_session=True
        )
        proc.log_path = self.log_dir / f"{name}.log"  # type: ignore[attr-defined]
        self.procs.append(proc)
        return proc

    def log(self, proc: subprocess.Popen[bytes]) -> str:
        return Path(proc.log_path).read_text(errors="replace")  # type: ignore[attr-defined]

    def stop(self, proc: subprocess.Popen[bytes], sig: int = signal.SIGINT, timeout: float = 20.0) -> int:
        """Signal the process and wait; SIGKILL its group if it does not end in time."""
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, sig)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)
        return int(proc.returncode)

    def kill_all(self) -> None:
        for proc in self.procs:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGKILL)
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(5)


@pytest.fixture
def processes(tmp_path: Path) -> Iterator[Processes]:
    procs = Processes(tmp_path)
    try:
        yield procs
    finally:
        procs.kill_all()


def wait_for(
    predicate: Callable[[], bool], timeout: float, what: str | Callable[[], str], interval: float = 0.05
) -> None:
    """Poll until ``predicate`` holds; fail naming ``what`` after a generous timeout.

    ``what`` may be a callable, read only on failure, to say the state the wait ended in.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(interval)
    pytest.fail(f"timed out after {timeout:.0f} s waiting for {what() if callable(what) else what}")


@pytest.fixture(scope="session")
def urban_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`stereovox simulate urban --frames 30 --seed 1` (640x480, PNG, full ground truth), made once per session."""
    from common.scenarios.simulate import simulate_to_file

    return simulate_to_file("urban", tmp_path_factory.mktemp("urban") / "urban.mcap", frames=30, seed=1)
