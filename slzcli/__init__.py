"""slz: UAV safe-landing-zone detection over recorded RGB-D flights."""

__version__ = "0.1.0"
