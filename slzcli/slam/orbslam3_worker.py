"""The ORB-SLAM3 worker process: owns the native system and answers the parent's track requests.

Started as a script (``python .../orbslam3_worker.py FD``, the socket to the parent on file descriptor FD), not
as a module of the package: a fresh interpreter (multiprocessing's spawn would re-run the parent's __main__)
that imports numpy and pyorbslam3 only, so it is ready in ~0.1 s where importing slzcli first took ~0.5 s of
every run's start. The protocol (the replies) is described in ``orbslam3.py``, which starts and feeds it.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from multiprocessing.connection import Connection

if __name__ == "__main__" and sys.path and os.path.abspath(sys.path[0]) == os.path.dirname(os.path.abspath(__file__)):
    sys.path.pop(0)   # a script's folder comes first on the path: here slz's own base.py, features.py, ...

import numpy as np  # after the path is cleaned


def serve(conn: Connection, vocab_path: str, settings_text: str, sensor: str = "rgbd") -> None:
    """Load the vocabulary, say ready (or the error), then track each frame sent until told to close."""
    import pyorbslam3 as pos

    with tempfile.TemporaryDirectory(prefix="slz-orbslam3-") as tmp:
        settings = os.path.join(tmp, "settings.yaml")
        with open(settings, "w") as f:
            f.write(settings_text)
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
                _, rgb, depth, t = msg
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
    _init, vocab_path, settings_text, sensor = conn.recv()
    serve(conn, vocab_path, settings_text, sensor)


if __name__ == "__main__":
    main()
