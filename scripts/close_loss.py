"""Does a Zenoh publisher that leaves the bus right after its last put lose that message?

The experiment behind ``bus.close_linger_s`` (common/bus.linger): a router on loopback, two
subscribers (one takes each message at once, one sleeps 0.3 s in its callback, as a recorder
compressing may), and a publisher process that puts forty 2 MB messages with BLOCK congestion
control, waits ``--linger`` seconds, undeclares and closes its session. Each trial prints how many
messages each subscriber got; the summary counts trials in which either lost any::

    .venv/bin/python scripts/close_loss.py --trials 10 --linger 0
    .venv/bin/python scripts/close_loss.py --trials 10 --linger 0.5

Each trial takes about 15 s.
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import zenoh

MESSAGES, SIZE_BYTES, SLOW_S, QUIET_S = 40, 2_000_000, 0.3, 4.0
REPO = Path(__file__).resolve().parents[1]


def client(port: int) -> zenoh.Session:
    endpoint = f"tcp/127.0.0.1:{port}"
    conf = f'{{mode: "client", connect: {{endpoints: ["{endpoint}"]}}, scouting: {{multicast: {{enabled: false}}}}}}'
    return zenoh.open(zenoh.Config.from_json5(conf))


def publish(port: int, linger_s: float) -> None:
    session = client(port)
    pub = session.declare_publisher("close_loss/x", congestion_control=zenoh.CongestionControl.BLOCK)
    time.sleep(1.0)  # the subscribers are declared before this process starts; let the routes settle
    payload = bytearray(SIZE_BYTES)
    for i in range(MESSAGES):
        payload[0:4] = i.to_bytes(4, "little")
        pub.put(bytes(payload))
    time.sleep(linger_s)
    pub.undeclare()
    session.close()


def subscribe(port: int, delay_s: float, out: Path) -> None:
    session = client(port)
    got: list[int] = []
    last = [time.monotonic()]

    def on_sample(sample: zenoh.Sample) -> None:
        got.append(int.from_bytes(sample.payload.to_bytes()[0:4], "little"))
        last[0] = time.monotonic()
        time.sleep(delay_s)

    sub = session.declare_subscriber("close_loss/x", zenoh.handlers.Callback(on_sample, indirect=False))
    out.with_suffix(".ready").touch()
    while time.monotonic() - last[0] < QUIET_S:
        time.sleep(0.1)
    sub.undeclare()
    session.close()
    out.write_text(str(len(got)))


def trial(linger_s: float, folder: Path) -> tuple[int, int]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    me = [sys.executable, __file__]
    router = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "router", "--listen", f"tcp/127.0.0.1:{port}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=REPO,
    )
    try:
        time.sleep(1.5)
        fast, slow = folder / "fast", folder / "slow"
        for path in (fast, slow, fast.with_suffix(".ready"), slow.with_suffix(".ready")):
            path.unlink(missing_ok=True)
        subs = [subprocess.Popen([*me, "sub", str(port), str(d), str(p)]) for d, p in ((0.0, fast), (SLOW_S, slow))]
        while not all(p.with_suffix(".ready").exists() for p in (fast, slow)):
            time.sleep(0.1)
        subprocess.run([*me, "pub", str(port), str(linger_s)], check=True)
        for p in subs:
            p.wait(60)
        return int(fast.read_text()), int(slow.read_text())
    finally:
        router.terminate()
        router.wait(10)


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] in ("pub", "sub"):
        port = int(sys.argv[2])
        if sys.argv[1] == "pub":
            publish(port, float(sys.argv[3]))
        else:
            subscribe(port, float(sys.argv[3]), Path(sys.argv[4]))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--linger", type=float, default=0.0, help="seconds between the last put and leaving")
    args = parser.parse_args()
    lossy = 0
    with tempfile.TemporaryDirectory() as tmp:
        for t in range(args.trials):
            fast, slow = trial(args.linger, Path(tmp))
            lossy += fast < MESSAGES or slow < MESSAGES
            print(f"trial {t + 1}: fast subscriber {fast} of {MESSAGES}, slow {slow} of {MESSAGES}", flush=True)
    print(f"linger {args.linger:.2f} s: {lossy} of {args.trials} trials lost a message")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
