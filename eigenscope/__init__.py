"""Eigenscope command line: ``eigenscope analyze|synth|probe|serve|worker|submit|export-openapi``."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("eigenscope")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"
