"""The package version: a leaf every module may read (the package facade imports the API lazily, so reading
the version from ``slzcli`` itself closed an import circle)."""

__version__ = "0.1.0"
