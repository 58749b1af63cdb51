"""The pure measuring library: ndarrays and dataclasses in and out.

No Celery, FastAPI, Redis or settings imports live below this package. One job per module:

- :mod:`~workers.pipeline.clipio` -- clip I/O: detection, validation and streaming of frames;
- :mod:`~workers.pipeline.model` -- the inputs and outputs (excitation, options, the result dataclasses);
- :mod:`~workers.pipeline.survey` and :mod:`~workers.pipeline.window` -- which frames to analyse;
- :mod:`~workers.pipeline.flow` -- dense optical flow; :mod:`~workers.pipeline.stream` -- the frames of a
  window read once into flow, depth and grey buffers;
- :mod:`~workers.pipeline.fft`, :mod:`~workers.pipeline.spectra`, :mod:`~workers.pipeline.peaks` -- per-pixel
  spectra, summed spectra and their peaks;
- :mod:`~workers.pipeline.segmentation` -- pixels grouped by spectral signature into object masks;
  :mod:`~workers.pipeline.bodies` -- the parts of one body ringing in several modes joined into one object;
- :mod:`~workers.pipeline.detection` -- which peaks are objects, and why the others are not;
- :mod:`~workers.pipeline.tracking` and :mod:`~workers.pipeline.registration` -- each object's motion;
- :mod:`~workers.pipeline.ringdown` (with :mod:`~workers.pipeline.lstsq`) -- the damped-oscillation fit;
- :mod:`~workers.pipeline.modes` -- each object's modes: frequency, damping and shape (pixels, metres);
- :mod:`~workers.pipeline.force` -- the excitation from a force sensor: a hold and release, or a strike;
- :mod:`~workers.pipeline.metric`, :mod:`~workers.pipeline.mechanics`, :mod:`~workers.pipeline.measure` --
  amplitude in metres, stiffness and mass, one object's figures;
- :mod:`~workers.pipeline.quality` -- why a figure may be unreliable;
- :mod:`~workers.pipeline.figures` -- images of the result, one pure function per figure;
- :mod:`~workers.pipeline.analysis` -- the stages wired together (:func:`analyze`);
- :mod:`~workers.pipeline.paper` -- the paper's recipe, for comparison;
- :mod:`~workers.pipeline.synth` -- ground-truth RGB-D scenes for tests, demos and benchmarks;
  :mod:`~workers.pipeline.synth_beam` -- struck cantilevers ringing in their bending modes.
"""
