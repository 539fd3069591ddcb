"""Ground truth for synthetic recordings: the true safe area, computed from scene GEOMETRY.

Safety raster (world XY, ``raster_m`` per cell): vertical rays from above give the top
surface of every cell: its height, slope and object. A cell is *usable* when its object is
landable (ground, ramps), its slope is within ``uav.max_slope_deg`` and no neighbour cell
differs in height by more than ``step_m`` (kerbs, box edges, ramp drops). A cell is *safe*
when every cell whose centre lies in the axis-aligned square of side footprint + 2 margin
centred on it is usable (an erosion). Outside the ground patch is unsafe. A pixel is safe
when the world XY of its rendered surface point falls in a safe cell; pixels that see
nothing are unsafe. Nothing here uses the terrain maps being evaluated.

Sidecar format (see datasets/GROUND_TRUTH.md): ``<recording>.gt.npz`` + ``<recording>.gt.json``.
The per-frame arrays are not read whole: ``safe_masks`` is stored uncompressed in the zip
(format v2) and memory-mapped, one frame unpacked on demand; ``object_ids`` (deflated, it
compresses ~50x) is read one frame at a time from the zip member. A sidecar of many
full-size frames then costs one frame of memory, not N.
"""

from __future__ import annotations

import struct
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Protocol

import cv2
import numpy as np
import numpy.typing as npt

from slzcli.bounds import load_json
from slzcli.config import GroundTruthCfg, UavCfg
from slzcli.errors import DatasetError

GT_FORMAT = "slz-ground-truth"
GT_VERSION = 2
READABLE_VERSIONS = (1, 2)            # v1: every member deflated (read the same way, masks kept packed)
RASTER_MEMBERS = ("raster_safe", "raster_usable", "raster_height_m", "raster_slope_deg", "raster_object_id",
                  "raster_origin_xy", "raster_resolution_m")
STORED_MEMBERS = ("safe_masks",)      # written uncompressed so that the loader can memory-map them
_ZIP_LOCAL_HEADER = struct.Struct("<4s5H3I2H")   # PKZIP local file header (30 bytes)


@dataclass(frozen=True, eq=False)
class SafetyRaster:
    """World-XY raster; cell (row r, col c) covers x in [x0 + c res, x0 + (c+1) res), y likewise with r.

    Row index grows with world y (row 0 is the southern edge), so ``np.flipud`` shows it north-up.
    """

    origin_xy: tuple[float, float]
    resolution_m: float
    safe: np.ndarray          # bool (rows, cols): a UAV centred on the cell can land
    usable: np.ndarray        # bool: the cell itself is landable, level and off any step
    height_m: np.ndarray      # float32: top surface height, NaN where nothing
    slope_deg: np.ndarray     # float32: top surface slope against world z
    object_id: np.ndarray     # uint16: object of the top surface, 0 = nothing

    def cells(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, col, inside) of world points; rows/cols clipped where outside."""
        x0, y0 = self.origin_xy
        with np.errstate(invalid="ignore"):
            c = np.floor((x - x0) / self.resolution_m)
            r = np.floor((y - y0) / self.resolution_m)
            inside = (c >= 0) & (r >= 0) & (c < self.safe.shape[1]) & (r < self.safe.shape[0])
        r = np.where(inside, r, 0).astype(np.int64)
        c = np.where(inside, c, 0).astype(np.int64)
        return r, c, inside

    def safe_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """True where world (x, y) lies in a safe cell; NaN or outside -> False."""
        r, c, inside = self.cells(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return inside & self.safe[r, c]


def compute_raster(cast: Any, extent_xy: tuple[float, float, float, float], top_z_m: float,
                   landable_of_part: np.ndarray, object_of_part: np.ndarray,
                   uav: UavCfg, cfg: GroundTruthCfg) -> SafetyRaster:
    """Rasterise the scene from above and erode the usable cells by the UAV footprint + margin.

    ``cast(origins, dirs)`` is ``Renderer.cast``: it returns t, part (-1 = none), hit, normal.
    """
    res = cfg.raster_m
    xmin, xmax, ymin, ymax = extent_xy
    cols = int(np.ceil((xmax - xmin) / res))
    rows = int(np.ceil((ymax - ymin) / res))
    xc = xmin + (np.arange(cols) + 0.5) * res
    yc = ymin + (np.arange(rows) + 0.5) * res
    X, Y = np.meshgrid(xc, yc)
    origins = np.stack([X.ravel(), Y.ravel(), np.full(X.size, top_z_m)], axis=1)
    dirs = np.broadcast_to(np.array([0.0, 0.0, -1.0]), origins.shape)
    ans = cast(origins, dirs)
    hit, part = ans["hit"], ans["part"]
    height = np.where(hit, top_z_m - ans["t"], np.nan).reshape(rows, cols)
    nz = np.abs(ans["normal"][:, 2])
    slope = np.where(hit, np.degrees(np.arccos(np.clip(nz, 0.0, 1.0))), np.nan).reshape(rows, cols)
    obj = np.zeros(hit.shape, dtype=np.uint16)
    obj[hit] = object_of_part[part[hit]]
    landable = np.zeros(hit.shape, dtype=bool)
    landable[hit] = landable_of_part[part[hit]]
    landable = landable.reshape(rows, cols)

    # Height jump to any 8-neighbour; holes count as infinitely deep so their rims are unusable.
    h = np.where(np.isfinite(height), height, -1e6).astype(np.float32)
    kernel = np.ones((3, 3), np.uint8)
    hmax = cv2.dilate(h, kernel, borderType=cv2.BORDER_REPLICATE)
    hmin = cv2.erode(h, kernel, borderType=cv2.BORDER_REPLICATE)
    step = np.maximum(hmax - h, h - hmin) > cfg.step_m
    with np.errstate(invalid="ignore"):
        level = slope <= uav.max_slope_deg + cfg.slope_tolerance_deg
    usable = landable & level & ~step & np.isfinite(height)

    half = [int(np.floor((L / 2 + uav.clearance_m) / res)) for L in uav.footprint_m]
    if 2 * half[0] + 1 > cols or 2 * half[1] + 1 > rows:   # the UAV is larger than the scene: nowhere is safe
        safe = np.zeros((rows, cols), bool)                 # (and the kernel is never built: 1e6 m asked TiB)
    else:
        k = np.ones((2 * half[1] + 1, 2 * half[0] + 1), np.uint8)   # rows along y (L2), cols along x (L1)
        safe = cv2.erode(usable.astype(np.uint8), k, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    return SafetyRaster((float(xmin), float(ymin)), float(res), safe, usable, height.astype(np.float32),
                        slope.astype(np.float32), obj.reshape(rows, cols))


def pixel_safe_mask(raster: SafetyRaster, point_world: np.ndarray, hit: np.ndarray) -> np.ndarray:
    """Per-pixel truth: the rendered surface point of the pixel lies in a safe raster cell."""
    return hit & raster.safe_at(point_world[..., 0], point_world[..., 1])


# ----------------------------------------------------------------------------- sidecar
def sidecar_paths(recording: str | Path) -> tuple[Path, Path]:
    """``<recording>.gt.npz`` and ``<recording>.gt.json`` next to the recording (file or folder)."""
    base = str(recording).rstrip("/\\")
    return Path(base + ".gt.npz"), Path(base + ".gt.json")


class FrameStack(Protocol):
    """(N, H, W) per-frame data read one frame at a time: ``len``, ``shape``, ``stack[i]``."""

    shape: tuple[int, ...]

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> np.ndarray: ...


class PackedMasks:
    """Bool (N, H, W) masks held bit-packed along x (in memory or memory-mapped); ``[i]`` unpacks one frame."""

    def __init__(self, packed: np.ndarray, width: int) -> None:
        self.packed = packed
        self.shape: tuple[int, ...] = (packed.shape[0], packed.shape[1], int(width))

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, i: int) -> np.ndarray:
        return np.unpackbits(self.packed[int(i)], axis=-1, count=self.shape[2]).astype(bool)

    def __array__(self, dtype: npt.DTypeLike | None = None, copy: bool | None = None) -> np.ndarray:
        out = np.unpackbits(np.asarray(self.packed), axis=-1, count=self.shape[2]).astype(bool)
        return out if dtype is None else out.astype(dtype)


class ZipMemberFrames:
    """A deflated (N, ...) ``.npy`` member of a zip, read one frame per access (seek + read, no full load)."""

    def __init__(self, path: Path, member: str, shape: tuple[int, ...], dtype: np.dtype, data_offset: int) -> None:
        self.path, self.member, self.dtype, self._offset = path, member, dtype, data_offset
        self.shape = tuple(int(v) for v in shape)
        self._frame_bytes = int(np.prod(self.shape[1:], dtype=np.int64)) * dtype.itemsize

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, i: int) -> np.ndarray:
        i = int(i)
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} of {len(self)}")
        i %= len(self)
        try:
            with zipfile.ZipFile(self.path) as zf, zf.open(self.member) as f:
                f.seek(self._offset + i * self._frame_bytes)
                data = f.read(self._frame_bytes)
        except (OSError, zipfile.BadZipFile) as err:
            raise DatasetError(self.path, f"cannot read {self.member} frame {i} ({err})") from err
        if len(data) != self._frame_bytes:
            raise DatasetError(self.path, f"{self.member} is cut short at frame {i}")
        return np.frombuffer(data, self.dtype).reshape(self.shape[1:])

    def __array__(self, dtype: npt.DTypeLike | None = None, copy: bool | None = None) -> np.ndarray:
        out = np.stack([self[i] for i in range(len(self))]) if len(self) else np.empty(self.shape, self.dtype)
        return out if dtype is None else out.astype(dtype)


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Everything a synthetic recording's truth holds; frames indexed like the recording's frames.

    ``safe_masks`` and ``object_ids`` are (N, H, W) arrays or lazy ``FrameStack``s (a loaded
    sidecar): index them one frame at a time (``np.asarray`` reads all of it).
    """

    stamps_ns: np.ndarray         # (N,) int64, the frame stamps of the recording
    T_world_camera: np.ndarray    # (N, 4, 4) true camera poses
    safe_masks: np.ndarray | FrameStack     # (N, H, W) bool
    object_ids: np.ndarray | FrameStack     # (N, H, W) uint16, 0 = nothing
    raster: SafetyRaster
    objects: tuple[dict[str, Any], ...]   # {"id", "name", "kind", "landable"}
    header: dict[str, Any] = field(default_factory=dict)
    stamp_tolerance_ns: int = 0   # default of index_of / safe_mask: synth.ground_truth.stamp_tolerance_ms

    def __len__(self) -> int:
        return len(self.stamps_ns)

    def index_of(self, stamp_ns: int, tolerance_ns: int | None = None) -> int:
        """Frame index with this stamp (within tolerance, default ``stamp_tolerance_ns``); DatasetError when none."""
        tol = self.stamp_tolerance_ns if tolerance_ns is None else tolerance_ns
        i = int(np.argmin(np.abs(self.stamps_ns - int(stamp_ns))))
        if abs(int(self.stamps_ns[i]) - int(stamp_ns)) > tol:
            raise DatasetError(self.header.get("recording", "ground truth"),
                               f"no ground-truth frame at stamp {stamp_ns} ns")
        return i

    def safe_mask(self, stamp_ns: int, tolerance_ns: int | None = None) -> np.ndarray:
        """(H, W) bool truth of the frame with this stamp (one frame read, not the stack)."""
        return np.asarray(self.safe_masks[self.index_of(stamp_ns, tolerance_ns)], dtype=bool)


def raster_arrays(r: SafetyRaster) -> dict[str, np.ndarray]:
    """The raster's arrays of the ``.gt.npz`` file (names are part of the documented format)."""
    return {"raster_safe": r.safe, "raster_usable": r.usable, "raster_height_m": r.height_m,
            "raster_slope_deg": r.slope_deg, "raster_object_id": r.object_id,
            "raster_origin_xy": np.asarray(r.origin_xy, dtype=np.float64),
            "raster_resolution_m": np.asarray(r.resolution_m, dtype=np.float64)}


def ground_truth_arrays(gt: GroundTruth) -> dict[str, np.ndarray]:
    """All arrays of the ``.gt.npz`` file for an in-memory GroundTruth (masks bit-packed along x)."""
    return {"stamps_ns": gt.stamps_ns.astype(np.int64), "T_world_camera": gt.T_world_camera.astype(np.float64),
            "safe_masks": np.packbits(np.asarray(gt.safe_masks, dtype=bool), axis=-1),
            "object_ids": np.asarray(gt.object_ids).astype(np.uint16), **raster_arrays(gt.raster)}


def _member_array_info(zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> tuple[tuple[int, ...], np.dtype, int]:
    """Shape, dtype and the offset of the data inside the member (after the ``.npy`` header)."""
    with zf.open(info) as f:
        version = np.lib.format.read_magic(f)
        if version not in ((1, 0), (2, 0)):
            raise ValueError(f"{info.filename}: .npy format {version} is not read lazily")
        shape, fortran, dtype = (np.lib.format.read_array_header_1_0(f) if version == (1, 0)
                                 else np.lib.format.read_array_header_2_0(f))
        if fortran or dtype.hasobject:
            raise ValueError(f"{info.filename}: only C-order plain arrays are read lazily")
        return tuple(shape), dtype, f.tell()


def _stored_member_offset(fh: BinaryIO, info: zipfile.ZipInfo) -> int:
    """File offset of an uncompressed member's first byte (after its local header)."""
    fh.seek(info.header_offset)
    fields = _ZIP_LOCAL_HEADER.unpack(fh.read(_ZIP_LOCAL_HEADER.size))
    if fields[0] != b"PK\x03\x04":
        raise ValueError(f"{info.filename}: bad local header")
    return info.header_offset + _ZIP_LOCAL_HEADER.size + fields[-2] + fields[-1]


def _lazy_member(path: Path, name: str) -> np.ndarray | ZipMemberFrames:
    """An (N, ...) member without reading it: a read-only memmap when stored, else frame-by-frame zip reads."""
    with open(path, "rb") as fh, zipfile.ZipFile(fh) as zf:
        info = zf.getinfo(f"{name}.npy")
        shape, dtype, data_offset = _member_array_info(zf, info)
        if info.compress_type == zipfile.ZIP_STORED:
            start = _stored_member_offset(fh, info) + data_offset
            if not shape or 0 in shape:   # mmap cannot map zero bytes
                return np.zeros(shape, dtype)
            return np.memmap(path, dtype=dtype, mode="r", offset=start, shape=shape)
    return ZipMemberFrames(path, info.filename, shape, dtype, data_offset)


BINDING_KEY = "recording_files"   # .gt.json: the recording's files this truth belongs to (size, sha256)
UNBOUND = ("is not bound to its recording (written by an slz before sidecars were bound): it is used unchecked; "
           "write it again with slz synth to bind it")


def load_ground_truth(recording_path: str | Path) -> GroundTruth:
    """Read the ground-truth sidecar of a recording written by ``slz synth`` (per-frame arrays lazily).

    Its binding to the recording (``BINDING_KEY``) is checked by ``evaluate.truth.ground_truth_of``.
    """
    npz_path, json_path = sidecar_paths(recording_path)
    if not npz_path.is_file() or not json_path.is_file():
        raise DatasetError(recording_path, f"no ground truth ({npz_path.name} and {json_path.name} expected "
                                           "next to it; only `slz synth` recordings have one)")
    header = load_json(json_path, "ground-truth header (.gt.json)")
    if not isinstance(header, dict) or header.get("format") != GT_FORMAT \
            or header.get("version") not in READABLE_VERSIONS:
        raise DatasetError(json_path, f"not a {GT_FORMAT} v{'/'.join(map(str, READABLE_VERSIONS))} header")
    try:
        width = int(header["image"]["width"])
        with np.load(npz_path) as z:   # an NpzFile reads a member only when asked
            a = {k: z[k] for k in ("stamps_ns", "T_world_camera", *RASTER_MEMBERS)}
        packed = _lazy_member(npz_path, "safe_masks")
        if isinstance(packed, ZipMemberFrames):   # a v1 file: deflated; keep it packed in memory (1 bit/pixel)
            packed = np.asarray(packed)
        object_ids = _lazy_member(npz_path, "object_ids")
        raster = SafetyRaster(tuple(a["raster_origin_xy"].tolist()),
                              float(np.asarray(a["raster_resolution_m"]).reshape(-1)[0]),
                              a["raster_safe"], a["raster_usable"], a["raster_height_m"], a["raster_slope_deg"],
                              a["raster_object_id"])
        return GroundTruth(a["stamps_ns"], a["T_world_camera"], PackedMasks(packed, width), object_ids, raster,
                           tuple(header["objects"]), header)
    except KeyError as err:
        raise DatasetError(npz_path, f"ground truth lacks {err}") from err
    except (OSError, ValueError, zipfile.BadZipFile) as err:
        raise DatasetError(npz_path, f"unreadable ground truth ({err})") from err
