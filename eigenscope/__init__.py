"""Eigenscope command line: ``eigenscope analyze|synth|probe|serve|worker|submit|export-openapi``."""

import os

# The analysis runs its own threads (flow pairs, FFT blocks, registration) and calls BLAS only on small
# matrices. OpenBLAS's thread pool then only fights those threads for the cores: a 255 x 255 eigh took
# 1.1 s instead of 10 ms on two busy cores. OpenCV's pool does the same inside each of two concurrent
# DIS flows (1.7 s instead of 2.8 s for 255 pairs with one OpenCV thread). These must be set before
# numpy and cv2 are first imported, which is why they live in the package every entry point (CLI,
# worker, server) imports first. A value set in the environment wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM"):
    os.environ.setdefault(_var, "1")
# numpy asks the kernel for transparent huge pages on every large array. Where the kernel then compacts
# memory synchronously to find them (THP defrag "madvise", the common default), the first touch of an
# analysis's buffers costs more than the small pages it saves: 640x480x256 end to end took 0.2-0.25 s
# longer with it, over repeated runs; a warm worker's analysis with images 15-17 % (bench/devices.py).
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")


def __getattr__(name: str) -> str:
    """``eigenscope.__version__``, read from :mod:`backend.version` (where it is written) only when
    asked: importing ``api_schemas`` loads pydantic, which most commands do not need at start."""
    if name == "__version__":
        from backend.version import __version__

        return __version__
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
