"""slz: UAV safe-landing-zone detection over recorded RGB-D flights.

The Python API (README "Python API"): ``slzcli.detect(recording_or_frames, config) -> RunResult``,
``slzcli.load_config(path, overrides)``, and the types ``Frame``, ``Intrinsics``, ``RunResult``,
``Config``. They are imported on first use: ``import slzcli`` stays light (no numpy, OpenCV or SLAM).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from slzcli.version import __version__

__all__ = ["Config", "Frame", "Intrinsics", "RunResult", "SlzError", "__version__", "detect", "load_config"]

if TYPE_CHECKING:
    from slzcli.api import detect, load_config
    from slzcli.config import Config
    from slzcli.errors import SlzError
    from slzcli.types import Frame, Intrinsics, RunResult

_LAZY = {"detect": "slzcli.api", "load_config": "slzcli.api", "Config": "slzcli.config", "SlzError": "slzcli.errors",
         "Frame": "slzcli.types", "Intrinsics": "slzcli.types", "RunResult": "slzcli.types"}


def __getattr__(name: str) -> Any:
    """The API names, imported when first used (PEP 562)."""
    if name not in _LAZY:
        raise AttributeError(f"module 'slzcli' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(_LAZY[name]), name)
