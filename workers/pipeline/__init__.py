"""The pure measuring library: ndarrays and dataclasses in and out.

No Celery, FastAPI, Redis or settings imports live below this package. Stages, one module each:

- :mod:`workers.pipeline.clipio` -- clip I/O: detection, validation and streaming of frames;
- :mod:`workers.pipeline.survey` -- a cheap look at a whole long clip that chooses the analysis window;
- :mod:`workers.pipeline.flow` -- dense optical flow between consecutive frames;
- :mod:`workers.pipeline.spectrum` -- per-pixel spectra, the summed spectrum and frequency estimation;
- :mod:`workers.pipeline.segmentation` -- pixels grouped by spectral signature into object masks;
- :mod:`workers.pipeline.mechanics` -- amplitude in metres, damping, stiffness and mass;
- :mod:`workers.pipeline.render` -- images of the result;
- :mod:`workers.pipeline.analysis` -- the stages wired together (:func:`analyze`);
- :mod:`workers.pipeline.synth` -- ground-truth RGB-D scenes for tests, demos and benchmarks.
"""
