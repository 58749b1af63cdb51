"""The Eigenscope web service: the HTTP layer.

The FastAPI application lives in :mod:`service.app` (``create_app()``), its routes in
:mod:`service.routes`, the job and stream logic behind them in :mod:`service.jobs`, :mod:`service.clips`
and :mod:`service.streams`. What the API shares with the workers (settings, the job store, storage, the
broker, the stream transport, errors, logs, metric families, the version) is the package :mod:`backend`,
which imports nothing from here.

Nothing is imported here, so importing a light module does not pull in the web stack.
"""
