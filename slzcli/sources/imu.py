"""IMU samples of a ROS recording (ROS 1, ROS 2, MCAP): sensor_msgs/Imu, rotated into the colour optical frame.

Which topics: ``camera.gravity.imu.topic`` when set; else every sensor_msgs/Imu topic not named
as ground truth, a topic carrying both accelerometer and gyro (realsense-ros ``/camera/imu``
with ``unite_imu_method``, ``/imu/data``, ``/mavros/imu/data``, a ZED's or an OAK's ``imu/data``)
before a separate accelerometer (realsense-ros ``/camera/accel/sample``, librealsense's
``/device_0/sensor_2/Accel_0/imu/data``) with the gyro beside it (``gyro/sample``, ``Gyro_0``),
and within each kind the topic sharing the colour topic's first namespace. The IMU-to-camera
rotation comes from the messages' frame ids and /tf_static (else /tf's first messages; realsense-ros
publishes ``camera_accel_optical_frame`` and ``camera_color_optical_frame``), or from a
librealsense recorder's per-stream extrinsics. An IMU that cannot be placed is not used.
"""

from __future__ import annotations

import logging
from collections.abc import Generator
from contextlib import closing, suppress
from dataclasses import dataclass

import numpy as np

from slzcli.config import ImuGravityCfg
from slzcli.errors import DatasetError, DecodeError, SlzError
from slzcli.sources import decode, tf
from slzcli.sources import ros_types as ros
from slzcli.sources.message_log import MessageLog, RawMessage
from slzcli.sources.messages import MessageRecording
from slzcli.sources.ros_types import Message
from slzcli.sources.topics import TRANSFORM, is_ground_truth, normalise_msgtype

log = logging.getLogger(__name__)
IMU = "sensor_msgs/msg/Imu"
TF_TOPIC = "/tf"
NO_IMU = "no sensor_msgs/Imu topic"


@dataclass(frozen=True, eq=False)
class ImuSamples:
    """Specific force and angular rate in the colour optical frame, with their stamps (ns)."""

    stamps_ns: np.ndarray
    accel: np.ndarray                 # (N, 3) m/s^2
    gyro_stamps_ns: np.ndarray | None
    gyro: np.ndarray | None           # (M, 3) rad/s
    detail: str                       # topics and frames, for the reports


def imu_topics(topics: dict[str, str], color_topic: str | None, wanted: str = "") -> tuple[str, str | None] | None:
    """(accelerometer topic, gyro topic or None when the same or absent), or None without an IMU."""
    imus = sorted(t for t, m in topics.items() if normalise_msgtype(m) == IMU and not is_ground_truth(t))
    if wanted:
        return (wanted, None) if wanted in topics else None
    if not imus:
        return None
    home = (color_topic or "").strip("/").split("/")[0]

    def rank(topic: str) -> tuple[int, str]:
        return (0 if topic.strip("/").split("/")[0] == home else 1, topic)

    gyro_only = [t for t in imus if "gyro" in t.lower()]
    accel_only = [t for t in imus if "accel" in t.lower()]
    united = [t for t in imus if t not in gyro_only and t not in accel_only]
    if united:
        return min(united, key=rank), None
    if accel_only:
        accel = min(accel_only, key=rank)
        prefix = accel.lower().replace("accel", "gyro")
        gyro = next((g for g in sorted(gyro_only, key=rank) if g.lower() == prefix), None)
        return accel, gyro or (min(gyro_only, key=rank) if gyro_only else None)
    return None  # a gyro alone says nothing of gravity


def read_imu(rec: MessageRecording, cfg: ImuGravityCfg) -> ImuSamples | str:
    """The recording's IMU in the colour optical frame, or why there is none (a sentence).

    ``rec``: an open ``sources.messages.MessageRecording`` (its message log and its setup scan).
    """
    msglog = rec.log
    topics = msglog.topics()
    setup = rec.camera_setup()
    color = setup.choices.color.topic
    chosen = imu_topics(topics, color, cfg.topic)
    if chosen is None:
        if cfg.topic:
            return f"camera.gravity.imu.topic {cfg.topic} is not in the recording"
        return NO_IMU
    accel_topic, gyro_topic = chosen
    if normalise_msgtype(topics[accel_topic]) != IMU:
        return f"{accel_topic} is {topics[accel_topic]}, not sensor_msgs/Imu"
    acc = _read(msglog, accel_topic, cfg.max_messages, want_gyro=gyro_topic is None)
    if isinstance(acc, str):
        return acc
    stamps, accel, gyro_part, frame = acc
    gyro_stamps: np.ndarray | None = stamps if gyro_part is not None else None
    gyro = gyro_part
    gyro_frame = frame
    if gyro_topic is not None:
        g = _read(msglog, gyro_topic, cfg.max_messages, want_gyro=True)
        if not isinstance(g, str) and g[2] is not None:
            gyro_stamps, gyro, gyro_frame = g[0], g[2], g[3]
    camera = setup.first_color_frame_id() or ""
    static, stream_tf = _static_transforms(msglog, topics)
    R = _rotation(msglog, topics, static, stream_tf, accel_topic, color, frame, camera)
    if isinstance(R, str):
        return R
    accel = accel @ R.T
    if gyro is not None:
        Rg = R if gyro_frame == frame else _rotation(msglog, topics, static, stream_tf, gyro_topic or accel_topic,
                                                     color, gyro_frame, camera)
        gyro = None if isinstance(Rg, str) else gyro @ Rg.T
        gyro_stamps = None if gyro is None else gyro_stamps
    where = accel_topic + (f" + {gyro_topic}" if gyro_topic and gyro is not None else "")
    rotation = "same frame" if frame == camera else f"{frame or '(no frame id)'} -> {camera} rotated"
    return ImuSamples(stamps, accel, gyro_stamps, gyro, f"{where}, {len(stamps)} samples, {rotation}")


def _read(msglog: MessageLog, topic: str, limit: int, want_gyro: bool
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, str] | str:
    """(stamps, accel, gyro or None, frame id) of one Imu topic, the first ``limit`` messages."""
    stamps: list[int] = []
    acc: list[tuple[float, float, float]] = []
    gyr: list[tuple[float, float, float]] = []
    frame = ""
    bad = 0
    with closing(_messages(msglog, topic)) as messages:
        for raw in messages:
            if len(stamps) >= limit:
                break
            try:
                m: ros.Imu = msglog.deserialize(raw.topic, raw.data)
                stamp = decode.stamp_ns(m.header) or raw.log_ns
                a, w = m.linear_acceleration, m.angular_velocity
                acc.append((float(a.x), float(a.y), float(a.z)))
                gyr.append((float(w.x), float(w.y), float(w.z)))
                stamps.append(stamp)
                frame = frame or str(m.header.frame_id).lstrip("/")
            except (DecodeError, AttributeError, TypeError, ValueError):
                bad += 1
    if not stamps:
        return f"{topic}: no readable sensor_msgs/Imu message" + (f" ({bad} unreadable)" if bad else "")
    order = np.argsort(np.asarray(stamps, np.int64), kind="stable")
    t = np.asarray(stamps, np.int64)[order]
    a_arr = np.asarray(acc, np.float64)[order]
    g_arr = np.asarray(gyr, np.float64)[order]
    has_gyro = want_gyro and bool(np.any(g_arr != 0.0))
    return t, a_arr, g_arr if has_gyro else None, frame


def _messages(msglog: MessageLog, topic: str) -> Generator[RawMessage, None, None]:
    try:
        yield from msglog.messages([topic])
    except SlzError:
        raise
    except Exception as err:  # third-party reader errors (a damaged file), named once
        raise DatasetError(msglog.path, f"cannot read {topic} ({type(err).__name__}: {err})") from err


def _static_transforms(msglog: MessageLog, topics: dict[str, str]
                       ) -> tuple[dict[str, tuple[str, np.ndarray]], dict[str, np.ndarray]]:
    """/tf_static's tree and a librealsense recorder's per-stream extrinsics (``.../tf/0``)."""
    static: dict[str, tuple[str, np.ndarray]] = {}
    if tf.TF_STATIC in topics:
        static = tf.static_tree(_decoded(msglog, tf.TF_STATIC))
    stream_tf: dict[str, np.ndarray] = {}
    for topic in sorted(t for t, m in topics.items() if normalise_msgtype(m) == TRANSFORM and "/tf/" in t):
        for m in _decoded(msglog, topic):
            with suppress(DecodeError, AttributeError):
                stream_tf[topic] = decode.transform_matrix(m.translation, m.rotation)
            break
    return static, stream_tf


def _decoded(msglog: MessageLog, topic: str) -> Generator[Message, None, None]:
    with closing(_messages(msglog, topic)) as messages:
        for raw in messages:
            try:
                yield msglog.deserialize(raw.topic, raw.data)
            except DecodeError:
                continue


def _rotation(msglog: MessageLog, topics: dict[str, str], static: dict[str, tuple[str, np.ndarray]],
              stream_tf: dict[str, np.ndarray], imu_topic: str, color_topic: str | None, imu_frame: str,
              camera: str) -> np.ndarray | str:
    """R_camera_imu, or why it is unknown."""
    if imu_frame and imu_frame == camera:
        return np.eye(3)
    prefix = {"imu": _stream_prefix(imu_topic, "/imu/data"), "color": _stream_prefix(color_topic, "/image/data")}
    ref = {role: T for role, p in prefix.items() if p
           for topic, T in sorted(stream_tf.items(), reverse=True) if topic.startswith(p + "/tf/")}
    if "imu" in ref and "color" in ref:  # T_stream_ref of each (see camera_setup.py _depth_extrinsics)
        return (ref["color"] @ np.linalg.inv(ref["imu"]))[:3, :3]
    if not imu_frame or not camera:
        return (f"{imu_topic}: its frame id {imu_frame or '(empty)'} cannot be related to the colour frame "
                f"{camera or '(empty)'}: not used for gravity")
    R = _link(static, imu_frame, camera)
    if R is None and TF_TOPIC in topics:
        tree = dict(static)
        with closing(_decoded_limited(msglog, TF_TOPIC, tf.MAX_TF_MESSAGES)) as messages:
            for msg in messages:
                for _, parent, child, T in tf.transforms(msg):
                    tree.setdefault(child, (parent, T))
                R = _link(tree, imu_frame, camera)
                if R is not None:
                    break
    if R is None:
        return (f"{imu_topic}: no /tf_static (or /tf) link from its frame {imu_frame} to the colour frame "
                f"{camera}: not used for gravity; record /tf_static (realsense-ros publishes it)")
    return R


def _decoded_limited(msglog: MessageLog, topic: str, limit: int) -> Generator[Message, None, None]:
    for i, m in enumerate(_decoded(msglog, topic)):
        if i >= limit:
            return
        yield m


def _link(tree: dict[str, tuple[str, np.ndarray]], a: str, b: str) -> np.ndarray | None:
    """R_b_a when both frames reach one root in ``tree``, else None."""
    try:
        ca, cb = decode.compose_chain(tree, a), decode.compose_chain(tree, b)
    except DecodeError:
        return None
    if ca is None or cb is None or ca[0] != cb[0]:  # not one tree (a frame in none is its own root)
        return None
    return np.asarray(cb[1][:3, :3].T @ ca[1][:3, :3])


def _stream_prefix(topic: str | None, tail: str) -> str:
    return topic[: -len(tail)] if topic and topic.endswith(tail) else ""
