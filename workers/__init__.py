"""Eigenscope workers: the pure measuring library (``workers.pipeline``), the analysis runner shared by the
CLI and the Celery tasks, and the Celery app itself.

Nothing is imported eagerly here, so that light modules (``workers.probe``) start fast.
"""
