"""The module-level Celery app for the ``celery`` command line (``celery -A workers.celery_main ...``).

Only the ``celery`` CLI (workers started by hand, Flower) imports this; the rest of the code builds its app
with :func:`workers.celery_app.create_celery`.
"""

from workers.celery_app import create_celery

app = create_celery()
