"""The run assembly: ``slz detect``, the Python API, ``slz compare`` and batch workers run detection here.

One file per role, read in the order a run goes:

- ``source.py``   what a run reads: an open recording or frames in memory (``Source``);
- ``tracking.py`` SLAM over the frames, each map segment gravity-aligned (``Tracker``, ``track``);
- ``step.py``     a frame due: its terrain maps once, every method's detection, the run's tables (``tally``);
- ``commit.py``   which detected site ``landing.json`` holds (``landing.commit``);
- ``run.py``      the one frame loop (``run``) and its sinks; ``detect_recording`` (the run folder)
                  and ``detect_in_memory`` (the API).

The methods are plug-ins (``slzcli.methods``): the run never asks which method it runs.
"""

from slzcli.pipeline.run import RunOptions, detect_recording

__all__ = ["RunOptions", "detect_recording"]
