"""``stereovox monitor --foxglove``: the vehicle live in the Foxglove app, over its WebSocket protocol.

The monitor's read-only bus session feeds a foxglove-sdk server (``foxglove.sdk.v1``) through
the conversion shared with ``stereovox export`` (``common.foxglove_convert``). Each input keeps
only its newest message (a viewer wants the present, not a backlog), and the costly conversions
(JPEG, point packing, one cube per voxel) are skipped while no Foxglove client subscribes.
"""

from __future__ import annotations

import logging
import sys
import threading
from typing import Any

import zenoh

from common import messages as sv
from common.bus import FifoSubscriber, LatestSubscriber, subscribe
from common.foxglove_convert import Channels, Converter

log = logging.getLogger(__name__)

#: inputs drawn whether or not anyone looks: they are small and carry the ego trajectory.
ALWAYS: tuple[str, ...] = ("odometry/ego", "tracker/obstacles")
#: inputs converted only while a client subscribes to one of the Foxglove topics they feed.
ON_DEMAND: dict[str, tuple[str, ...]] = {
    "camera/stereo": ("/camera/left", "/camera/calibration"),
    "stereo_depth/points": ("/points",),
    "stereo_depth/disparity": ("/disparity",),
    "voxel_mapper/clusters": ("/voxels", "/clusters"),
    "groundtruth/objects": ("/groundtruth/objects",),
}


class LiveView:
    """Newest-only subscribers of the drawn topics, converted and logged on one thread."""

    def __init__(self, session: zenoh.Session, vehicle: str, channels: Channels) -> None:
        self.channels = channels
        self.converter = Converter()
        self.wakeup = threading.Event()
        self.subs: dict[str, LatestSubscriber[Any] | FifoSubscriber[Any]] = {
            topic: subscribe(session, sv.key_for(topic, vehicle), sv.TOPICS[topic], "newest", wakeup=self.wakeup)
            for topic in (*ALWAYS, *ON_DEMAND)
        }
        self.converted = 0

    def step(self) -> None:
        """Convert whatever arrived since the last step (waiting a little for something to)."""
        self.wakeup.wait(0.2)
        self.wakeup.clear()
        for topic, sub in self.subs.items():
            item = sub.recv(0.0)
            if item is None or (topic in ON_DEMAND and not self.channels.watched(ON_DEMAND[topic])):
                continue
            self.channels.log(self.converter.convert(topic, item.msg))
            self.converted += 1

    def close(self) -> None:
        for sub in self.subs.values():
            sub.close()


def serve(session: zenoh.Session, vehicle: str, host: str, port: int, stop: threading.Event) -> int:
    """Serve until ``stop`` is set; prints the WebSocket address (port 0 picks a free one)."""
    import foxglove

    context = foxglove.Context()
    channels = Channels(context)
    server = foxglove.start_server(name=f"stereovox {vehicle}", host=host, port=port, context=context)
    print(f"monitor: foxglove server at ws://{host}:{server.port} (vehicle {vehicle})", file=sys.stderr, flush=True)
    view = LiveView(session, vehicle, channels)
    try:
        while not stop.is_set():
            view.step()
    finally:
        view.close()
        channels.close()
        server.stop()
    log.info("foxglove server stopped after %d messages converted", view.converted)
    return 0
