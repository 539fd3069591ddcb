"""The Python API: ``slzcli.detect`` and ``slzcli.load_config`` (re-exported, lazily, by ``slzcli``).

``detect`` is the run ``slz detect`` is (``pipeline.run``: one frame loop, the same commit rule and
summary), on a recording or on frames already in memory:

- frames (any iterable of ``slzcli.Frame``, e.g. from a driver or numpy arrays): nothing is read
  from or written to disk; the result is a ``RunResult`` in memory.
- a recording path without ``out_dir``: read once, nothing written, the same ``RunResult``.
- a recording path with ``out_dir``: exactly ``slz detect RECORDING -o OUT_DIR`` (the run folder,
  the rerun key, ``force``); the result is read back from the run folder it wrote.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

from slzcli.config import Config, load_config
from slzcli.errors import DatasetError

if TYPE_CHECKING:  # numpy comes with these: imported at the first call, so `import slzcli.cli` stays light
    from slzcli.types import Frame, RunResult

__all__ = ["detect", "load_config"]


def detect(source: str | Path | Iterable[Frame], config: Config | None = None, out_dir: str | Path | None = None,
           *, method: str | None = None, force: bool = False, timeout_s: float | None = None) -> RunResult:
    """Detect the landing site of one recording or of a stream of frames (see the module docstring).

    ``config``: ``load_config(...)`` (default: the packaged defaults). ``method``: a registered method
    (default ``scoring.method``). ``force`` and ``timeout_s`` as ``slz detect --force --timeout``.
    Frames need rgb (uint8 HxWx3), depth_m (float32 metres, NaN = none), intrinsics and a stamp;
    with ``T_world_camera`` on every frame the poses are used as recorded, else SLAM tracks them.
    Raises SlzError subclasses (ConfigError, DatasetError, ...) naming the file or key.
    """
    from slzcli.pipeline.run import RunOptions, detect_frames, detect_recording, detect_recording_in_memory
    from slzcli.pipeline.source import FRAMES_SOURCE
    from slzcli.timeout import StageLimit

    config = load_config() if config is None else config
    method = method or config.scoring.method
    if isinstance(source, (str, Path)):
        path = Path(source)
        if out_dir is not None:
            out = Path(out_dir)
            detect_recording(path, config, out, RunOptions(force, method, timeout_s))
            return _read_run(out)
        return detect_recording_in_memory(path, config, method, StageLimit(timeout_s, str(path)))
    if out_dir is not None:
        raise DatasetError(FRAMES_SOURCE, "out_dir needs a recording path: frames in memory are not written")
    return detect_frames(source, config, method, StageLimit(timeout_s, FRAMES_SOURCE))


def _read_run(out: Path) -> RunResult:
    """The RunResult of a run folder ``slz detect`` wrote (``committed``: None, it is not stored)."""
    from slzcli.bounds import load_json
    from slzcli.outputs.run_folder import read_run

    return read_run(load_json(out / "landing.json", "landing.json"), load_json(out / "run.json", "run.json"))
