"""ATE/RPE with Umeyama alignment, and the trajectory / keyframe writers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from slzcli.evaluate.slam import ate, rpe, umeyama
from slzcli.outputs.trajectory import KeyframeLog, parse_tum, tum_text, write_tum
from slzcli.slam.base import MapPoints


def _trajectory(n: int = 40, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", [0.1 * np.sin(i / 5), 0.05 * i / n, 0.3 * i / n]).as_matrix()
        T[:3, 3] = np.array([0.1 * i, np.sin(i / 7), 2 + 0.01 * i]) + rng.normal(0, 1e-3, 3)
        out.append(T)
    return out


def _moved(poses: list[np.ndarray], scale: float = 1.0) -> list[np.ndarray]:
    G = np.eye(4)
    G[:3, :3] = Rotation.from_euler("zyx", [1.0, -0.4, 0.3]).as_matrix()
    G[:3, 3] = [5.0, -2.0, 7.0]
    out = []
    for T in poses:
        S = T.copy()
        S[:3, 3] *= scale
        out.append(G @ S)
    return out


def test_ate_is_zero_for_a_rotated_and_translated_copy() -> None:
    truth = _trajectory()
    res = ate(_moved(truth), truth)
    assert res.rmse_m < 1e-9 and res.max_m < 1e-9 and res.n == len(truth)


def test_sim3_alignment_recovers_scale_and_se3_does_not() -> None:
    truth = _trajectory()
    est = _moved(truth, scale=0.5)
    assert ate(est, truth, with_scale=True).rmse_m < 1e-9
    assert abs(ate(est, truth, with_scale=True).alignment.scale - 2.0) < 1e-9
    assert ate(est, truth).rmse_m > 0.1


def test_ate_measures_a_known_offset_and_skips_missing_poses() -> None:
    truth = _trajectory()
    est = [T.copy() for T in truth]
    for T in est[::2]:
        T[:3, 3] += [0.0, 0.0, 0.02]   # alternate frames 2 cm up: best fit is +1 cm, error 1 cm each
    est[5] = None
    res = ate(est, truth)
    assert res.n == len(truth) - 1
    assert res.rmse_m == pytest.approx(0.01, abs=1e-3)


def test_rpe_zero_after_rigid_motion_and_measures_drift() -> None:
    truth = _trajectory()
    assert rpe(_moved(truth), truth).trans_rmse_m < 1e-9
    drift = [T.copy() for T in truth]
    for i, T in enumerate(drift):
        T[:3, 3] += [0.001 * i, 0, 0]  # 1 mm per frame along world x
    r = rpe(drift, truth, delta=1)
    assert r.trans_rmse_m == pytest.approx(0.001, rel=1e-6)
    assert r.rot_rmse_deg < 1e-6


def test_umeyama_rejects_too_few_points() -> None:
    with pytest.raises(ValueError):
        umeyama(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError):
        ate([np.eye(4)] * 2, [np.eye(4)] * 2)


def test_tum_round_trip(tmp_path) -> None:
    poses = _trajectory(25)
    stamps = [1_700_000_000_123_456_789 + i * 33_333_333 for i in range(25)]
    poses_with_gap: list[np.ndarray | None] = list(poses)
    poses_with_gap[3] = None
    write_tum(tmp_path / "trajectory.tum", stamps, poses_with_gap)
    text = (tmp_path / "trajectory.tum").read_text()
    assert text.splitlines()[1].split()[0] == "1700000000.123456789"
    s, T = parse_tum(text)
    assert len(s) == 24 and s[0] == stamps[0] and s[3] == stamps[4]
    np.testing.assert_allclose(T, np.stack(poses[:3] + poses[4:]), atol=1e-8)
    assert tum_text([], []).startswith("#")


def test_keyframes_npz_is_spooled_on_disk_and_complete(tmp_path) -> None:
    kfs = [MapPoints(np.arange(n, dtype=np.int64), np.full((n, 3), float(i)), np.zeros((n, 2)), i, 10 * i, np.eye(4))
           for i, n in enumerate((3, 0, 5))]
    log = KeyframeLog(tmp_path / "spool")
    for kf in kfs:
        log.append(kf)
    assert len(log) == 3
    log.write_npz(tmp_path / "keyframes.npz")
    z = np.load(tmp_path / "keyframes.npz")
    assert z["kf_index"].tolist() == [0, 1, 2] and z["kf_stamp_ns"].tolist() == [0, 10, 20]
    assert z["kf_T_world_camera"].shape == (3, 4, 4)
    assert z["point_kf"].tolist() == [0, 0, 0, 2, 2, 2, 2, 2]
    assert z["point_xyz_world"].shape == (8, 3) and z["point_pixels"].shape == (8, 2)
    np.testing.assert_array_equal(log.map_xyz(), np.vstack([k.xyz_world for k in kfs]))
    empty = KeyframeLog(tmp_path / "empty")
    empty.write_npz(tmp_path / "empty.npz")
    z = np.load(tmp_path / "empty.npz")
    assert z["point_xyz_world"].shape == (0, 3) and z["kf_T_world_camera"].shape == (0, 4, 4)
    assert len(KeyframeLog()) == 0 and KeyframeLog().map_xyz().shape == (0, 3)


# ----------------------------------------------------------------------------- PointCloud2 decoding
def _cloud(xyz: np.ndarray, *, big: bool = False, f64: bool = False, pad: int = 0, drop: str = "", height: int = 1):
    from types import SimpleNamespace as NS

    kind = (">" if big else "<") + ("f8" if f64 else "f4")
    size = 8 if f64 else 4
    step = 3 * size + 4 + pad  # x y z, an unrelated 4-byte field, padding
    n = len(xyz)
    width = n // height
    row_pad = 3
    buf = bytearray((step * width + row_pad) * height)
    for i, p in enumerate(xyz):
        r, c = divmod(i, width)
        off = r * (step * width + row_pad) + c * step
        buf[off:off + 3 * size] = np.asarray(p, kind).tobytes()
    fields = [NS(name=nm, offset=i * size, datatype=8 if f64 else 7, count=1)
              for i, nm in enumerate("xyz") if nm != drop]
    fields.append(NS(name="intensity", offset=3 * size, datatype=7, count=1))
    return NS(fields=fields, is_bigendian=big, point_step=step, width=width, height=height,
              row_step=step * width + row_pad, data=np.frombuffer(bytes(buf), np.uint8))


@pytest.mark.parametrize("kw", [{}, {"big": True}, {"f64": True}, {"pad": 5, "height": 2}])
def test_decode_pointcloud2_layouts(kw) -> None:
    from slzcli.sources.decode import decode_pointcloud2

    xyz = np.array([[1.0, 2.0, 3.0], [-4.5, 0.25, 8.0], [np.nan, 0.0, 0.0], [7.0, 8.0, 9.0]])
    got, ids = decode_pointcloud2(_cloud(xyz, **kw))
    np.testing.assert_allclose(got, xyz[[0, 1, 3]])  # the NaN point is dropped
    assert ids.tolist() == [-1, -1, -1]


def test_decode_pointcloud2_errors() -> None:
    from slzcli.errors import DecodeError
    from slzcli.sources.decode import decode_pointcloud2

    with pytest.raises(DecodeError, match="no z field"):
        decode_pointcloud2(_cloud(np.zeros((2, 3)), drop="z"))
    short = _cloud(np.zeros((4, 3)))
    short.data = short.data[:10]
    with pytest.raises(DecodeError, match="too few"):
        decode_pointcloud2(short)


def test_pose_log_grows_past_its_capacity_and_keeps_missing_poses_missing() -> None:
    from slzcli.outputs.trajectory import PoseLog

    log = PoseLog(capacity=2)
    poses = [np.eye(4) * (i + 1) if i % 3 else None for i in range(7)]
    for i, T in enumerate(poses):
        log.append(1000 + i, T)
    assert len(log) == 7 and log.stamps == list(range(1000, 1007))
    for got, want in zip(log.poses(), poses, strict=True):
        assert (got is None) == (want is None)
        if want is not None:
            np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("on_disk", [False, True])
def test_site_log_gives_back_the_points_of_any_site(tmp_path, on_disk) -> None:
    import csv

    from slzcli.outputs.site_log import SITE_COLUMNS, SiteLog

    log = SiteLog(tmp_path / "spool" if on_disk else None)
    rng = np.random.default_rng(0)
    stored = []
    for i in range(4):
        kept, chosen = rng.normal(size=(5 + i, 3)), rng.normal(size=(2 + i, 3))
        log.add_rows([dict.fromkeys(SITE_COLUMNS, i), dict.fromkeys(SITE_COLUMNS, i)])
        log.add_site(f"frame {i}", f"site {i}", kept, chosen)  # type: ignore[arg-type]  # the log stores them
        stored.append((kept, chosen))
    assert log.rows == 8 and [s.site for s in log.sites] == [f"site {i}" for i in range(4)]
    for entry, (kept, chosen) in zip(log.sites, stored, strict=True):
        got_kept, got_chosen = log.points(entry)
        np.testing.assert_array_equal(got_kept, kept)
        np.testing.assert_array_equal(got_chosen, chosen)
    log.write_csv(tmp_path / "sites.csv")
    rows = list(csv.DictReader((tmp_path / "sites.csv").open()))
    assert len(rows) == 8 and list(rows[0]) == list(SITE_COLUMNS) and rows[-1]["frame"] == "3"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ate_and_rpe_match_evo(seed: int) -> None:
    """evo, the ecosystem's trajectory evaluator, gives the same ATE (SE(3) and Sim(3) alignment) and RPE."""
    evo_metrics = pytest.importorskip("evo.core.metrics")
    from evo.core.trajectory import PoseTrajectory3D

    rng = np.random.default_rng(seed)
    n = 40
    truth = np.tile(np.eye(4), (n, 1, 1))
    truth[:, :3, :3] = Rotation.from_euler("xyz", rng.normal(0, 0.3, (n, 3))).as_matrix()
    truth[:, :3, 3] = np.cumsum(rng.normal(0, 0.2, (n, 3)), axis=0)
    off = np.eye(4)
    off[:3, :3] = Rotation.from_euler("z", 40, degrees=True).as_matrix()
    off[:3, 3] = [3.0, -1.0, 2.0]
    est = off @ truth
    est[:, :3, :3] = est[:, :3, :3] @ Rotation.from_euler("xyz", rng.normal(0, 0.02, (n, 3))).as_matrix()
    est[:, :3, 3] += rng.normal(0, 0.05, (n, 3))
    stamps = np.arange(n, dtype=float)

    for with_scale in (False, True):
        ref, mine = PoseTrajectory3D(poses_se3=list(truth), timestamps=stamps), \
            PoseTrajectory3D(poses_se3=list(est), timestamps=stamps)
        mine.align(ref, correct_scale=with_scale)
        ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
        ape.process_data((ref, mine))
        ours = ate(list(est), list(truth), with_scale=with_scale)
        assert ours.rmse_m == pytest.approx(ape.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-9, abs=1e-12)

    ref, mine = PoseTrajectory3D(poses_se3=list(truth), timestamps=stamps), \
        PoseTrajectory3D(poses_se3=list(est), timestamps=stamps)
    ours_rpe = rpe(list(est), list(truth), delta=1)
    for relation, value in ((evo_metrics.PoseRelation.translation_part, ours_rpe.trans_rmse_m),
                            (evo_metrics.PoseRelation.rotation_angle_deg, ours_rpe.rot_rmse_deg)):
        metric = evo_metrics.RPE(relation, delta=1, delta_unit=evo_metrics.Unit.frames, all_pairs=False)
        metric.process_data((ref, mine))
        # arccos of the trace (ours) and evo's rotation log differ by ~1e-7 deg near 0: far below any figure shown
        assert value == pytest.approx(metric.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-6, abs=1e-6)
