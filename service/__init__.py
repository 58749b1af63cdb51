"""The Eigenscope web service.

Modules that the worker side imports too, free of FastAPI: :mod:`service.settings` (configuration),
:mod:`service.store` (the SQL job and clip store), :mod:`service.storage` (the data directory),
:mod:`service.errors` (domain errors with their HTTP status). The FastAPI application lives in
:mod:`service.app` (``create_app()``), its routes in :mod:`service.routes`.

Nothing is imported here, so importing a light module does not pull in the web stack.
"""
