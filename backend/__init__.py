"""The back end that the API (:mod:`service`) and the workers (:mod:`workers`) share.

Job state (:mod:`backend.store`: clips, jobs, streams and the workers' leases in one SQL database), clip
and artifact storage (:mod:`backend.storage`), the Celery broker configuration both sides build from
(:mod:`backend.broker`), the stream transport between the API's WebSocket relay and a stream's worker
(:mod:`backend.stream_transport`), settings (:mod:`backend.settings`), the domain errors and their one
table of problem types (:mod:`backend.errors`), logs (:mod:`backend.logs`), the metric families and
collectors both sides expose (:mod:`backend.metrics`), bounded JSON parsing (:mod:`backend.strict_json`),
the URLs of a job's resources (:mod:`backend.urls`) and the version (:mod:`backend.version`).

It sits above :mod:`api_schemas` and below both :mod:`service` and :mod:`workers`: it never imports
``fastapi``, ``starlette`` or ``uvicorn``, nor :mod:`service`, :mod:`workers` or :mod:`eigenscope`
(``tests/unit/service/test_layering.py``). Nothing is imported here, so importing one light module (the
version, say) does not pull in the others.
"""
