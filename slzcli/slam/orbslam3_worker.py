"""The ORB-SLAM3 worker process: owns the native system and answers the parent's track requests.

Started as a script (``python .../orbslam3_worker.py FD BUF``, the socket to the parent on file descriptor FD,
the shared frame buffer on BUF), not as a module of the package: a fresh interpreter (multiprocessing's spawn
would re-run the parent's __main__) that imports numpy and pyorbslam3 only, so it is ready in ~0.1 s where
importing slzcli first took ~0.5 s of every run's start. The protocol (the replies) is described in
``orbslam3.py``, which starts and feeds it.

The images travel through a buffer both processes map (``frame_views``), the socket carries only the request:
pickled over the socket a 640x480 frame (2.1 MB) cost the parent ~4 ms of blocking send and the worker its
unpickling, every frame, on the path ORB-SLAM3's own rate is measured on. The buffer has ``SLOTS`` frames, so
that the next request waits in the socket while one is tracked (the worker never idles between frames); the
parent writes a slot only after the reply to the frame it held, and the worker copies the images out before
tracking, so what the native code keeps never changes under it.
"""

from __future__ import annotations

import mmap
import os
import sys
import time
from multiprocessing.connection import Connection

if __name__ == "__main__" and sys.path and os.path.abspath(sys.path[0]) == os.path.dirname(os.path.abspath(__file__)):
    sys.path.pop(0)   # a script's folder comes first on the path: here slz's own base.py, features.py, ...

import numpy as np  # after the path is cleaned

SLOTS = 2   # frames in the shared buffer: one tracked, the next waiting (the parent's in_flight)


def frame_bytes(height: int, width: int) -> int:
    """Size of one slot of the shared frame buffer: the RGB image (uint8) then the depth (float32 metres, 0 =
    none)."""
    return height * width * 3 + height * width * 4


def frame_views(buf: mmap.mmap, height: int, width: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The RGB and depth images of each slot, laid over the shared buffer (the one layout both processes use)."""
    size = frame_bytes(height, width)
    return [(np.ndarray((height, width, 3), np.uint8, buffer=buf, offset=k * size),
             np.ndarray((height, width), np.float32, buffer=buf, offset=k * size + height * width * 3))
            for k in range(SLOTS)]


def serve(conn: Connection, vocab_path: str, settings_text: str, sensor: str,
          views: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """Load the vocabulary, say ready (or the error), then track each frame sent until told to close."""
    import pyorbslam3 as pos

    # the settings live in memory, named by a /proc path the native loader opens like a file: nothing is left on
    # disk however the worker ends (a temporary folder stayed behind each time the parent killed a stuck worker)
    fd = os.memfd_create("slz-orbslam3-settings")
    os.write(fd, settings_text.encode())
    settings = f"/proc/self/fd/{fd}"
    try:
        system = pos.Slam(vocab_path, settings, pos.Sensor.MONOCULAR if sensor == "monocular" else pos.Sensor.RGBD)
    except Exception as err:
        conn.send(("error", f"{type(err).__name__}: {err}"))
        return
    conn.send(("ready", None))
    try:
        while True:
            msg = conn.recv()
            if msg[0] == "close":
                break
            _, slot, with_depth, t = msg
            rgb = views[slot][0].copy()
            depth = views[slot][1].copy() if with_depth else None
            t0 = time.perf_counter()
            try:
                r = system.track_monocular(rgb, t) if depth is None else system.track_rgbd(rgb, depth, t)
            except Exception as err:
                conn.send(("error", f"{type(err).__name__}: {err}"))
                continue
            pts = np.asarray(system.tracked_map_points(), np.float64).reshape(-1, 3)
            conn.send(("ok", int(r.state), None if r.pose_wc is None else np.asarray(r.pose_wc, np.float64),
                       int(r.num_tracked_points), pts, (time.perf_counter() - t0) * 1e3))
    finally:
        system.shutdown()
        conn.send(("closed", None))


def main() -> None:
    conn = Connection(int(sys.argv[1]))
    _init, vocab_path, settings_text, sensor, (height, width) = conn.recv()
    buf = mmap.mmap(int(sys.argv[2]), SLOTS * frame_bytes(height, width))   # unmapped when the process ends
    serve(conn, vocab_path, settings_text, sensor, frame_views(buf, height, width))


if __name__ == "__main__":
    main()
