"""The command line's heap and the cyclic garbage collector: a performance device (``bench/README.md``,
"Performance devices"; ``python bench/devices.py --figures cli --devices gc_freeze``).

A command that analyses one clip and exits first imports its libraries (numpy, OpenCV, pydantic, the
pipeline; matplotlib and pyfftw follow during the analysis): about 100 000 objects that live until the
process ends. CPython's cyclic collector goes over all of them at each of its full passes during the
analysis (two of them, 0.05-0.08 s) and again in the interpreter's teardown (0.15-0.2 s, three quarters
of it the collector's). :func:`settle` moves every object alive at that moment to the collector's
permanent generation (:func:`gc.freeze`): they are not gone over again; reference counting frees them as
before, and garbage made later is collected as before.

Only a process that runs one command and then exits settles its heap: the ``eigenscope`` executable
(:func:`eigenscope.cli.console_main`) says so with :func:`for_this_process`. A process that calls
:func:`eigenscope.cli.main` itself (a test, a notebook) keeps its collector as it was.

Measured (``bench/devices.py``, 15 alternating rounds a run): ``eigenscope analyze`` of a 320 x 240 x 128
clip 12.5-14.9 % faster (four runs), of the 640 x 480 x 256 clip 6.9-10.8 % (three runs; 9.4 % over their
45 rounds). Settling at exit only saved 6.8-7.0 %: the settle after the imports is the other half.
"""

from __future__ import annotations

import gc

_one_command = False


def for_this_process() -> None:
    """Let :func:`settle` act: this process runs one command, then exits."""
    global _one_command
    _one_command = True


def settle() -> None:
    """Move every object alive now out of the cyclic collector's reach (:func:`gc.freeze`) in a process
    that runs one command and exits (:func:`for_this_process`); nothing in any other. Called after a
    command's imports and before the process exits."""
    if _one_command:
        gc.freeze()
