"""The API's URLs of a job's resources, which the workers hand out too (a stream's ``result`` names its
job's artifacts by URL, as the job's own representation does)."""

from __future__ import annotations


def artifact_url(job_id: str, name: str, *, root_path: str = "") -> str:
    """The URL of artifact ``name`` (a file name of the job's outputs) of job ``job_id``."""
    return f"{root_path}/v1/jobs/{job_id}/artifacts/{name}"


def result_url(job_id: str, *, root_path: str = "") -> str:
    """The URL of job ``job_id``'s whole result (its ``result.json``)."""
    return f"{root_path}/v1/jobs/{job_id}/result"


__all__ = ["artifact_url", "result_url"]
