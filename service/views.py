"""How the API shows a job: the pure views of stored job records (JSON models, result summaries, webhook
state; artifact and result URLs from :mod:`backend.urls`) and the entity tags of representations.

Nothing here needs a :class:`~service.context.ServiceContext`: the context (for webhooks), the job logic of
:mod:`service.jobs`, the routes and the streams all build on these.
"""

from __future__ import annotations

import hashlib
from typing import Any

from api_schemas import JobModel, JobSummary
from backend.store import JobRecord
from backend.urls import artifact_url, result_url


def excitation_json(spec: Any) -> Any:
    """The request's excitation (one model, a list of them, or None) as stored JSON."""
    if spec is None:
        return None
    if isinstance(spec, list):
        return [item.model_dump(mode="json") for item in spec]
    return spec.model_dump(mode="json")


def callback_view(job: JobRecord) -> dict[str, Any] | None:
    """The state of a job's webhook, or None without one."""
    if job.callback_url is None:
        return None
    return {
        "url": job.callback_url,
        "status": job.callback_status or "waiting",
        "attempts": job.callback_attempts,
        "last_error": job.callback_error,
    }


def served_result(job: JobRecord, root_path: str) -> dict[str, Any] | None:
    """The job's result with its artifacts as URLs."""
    if job.result is None:
        return None
    result = dict(job.result)
    artifacts = result.get("artifacts")
    if isinstance(artifacts, dict):
        artifacts = dict(artifacts)
        artifacts.setdefault("result", "result.json")  # results stored before it was listed
        result["artifacts"] = {
            key: artifact_url(job.id, value, root_path=root_path) if isinstance(value, str) else value
            for key, value in artifacts.items()
        }
    return result


def _job_fields(job: JobRecord) -> dict[str, Any]:
    return {
        "id": job.id,
        "clip_id": job.clip_id,
        "status": job.status,
        "progress": job.progress,
        "stage": job.stage,
        "attempts": job.attempts,
        "excitation": job.excitation,
        "parameters": job.parameters,
        "force_log": job.force_log_summary,
        "created_at": job.created_at,
        "started_at": job.started_at,
        "finished_at": job.finished_at,
        "error": job.error,
        "callback": callback_view(job),
        "source": job.source,
    }


def job_view(job: JobRecord, *, root_path: str = "") -> JobModel:
    """The API representation of a job: artifacts in the result become URLs."""
    return JobModel.model_validate({**_job_fields(job), "result": served_result(job, root_path)})


def result_summary(result: dict[str, Any]) -> dict[str, Any]:
    """The headline of a stored result (``ResultSummary``): its main object's figures and counts."""
    objects = result.get("objects") or []
    main = objects[0] if objects else {}
    warnings = [q for q in result.get("quality") or [] if q.get("severity", "warning") != "info"]
    return {
        "eigenfrequency_hz": result.get("eigenfrequency_hz"),
        "eigenfrequency_uncertainty_hz": main.get("eigenfrequency_uncertainty_hz"),
        "damping_ratio": main.get("damping_ratio"),
        "stiffness_n_per_m": main.get("stiffness_n_per_m"),
        "mass_kg": main.get("mass_kg"),
        "objects": len(objects),
        "warnings": len(warnings),
    }


def job_summary_view(job: JobRecord, *, root_path: str = "") -> JobSummary:
    """A job as lists show it: no result, its summary and the URLs of the job and of ``result.json``."""
    succeeded = job.status == "succeeded" and job.result is not None
    return JobSummary.model_validate(
        {
            **_job_fields(job),
            "summary": result_summary(job.result) if succeeded and job.result is not None else None,
            "url": f"{root_path}/v1/jobs/{job.id}",
            "result_url": result_url(job.id, root_path=root_path) if succeeded else None,
        }
    )


def etag_of(body: bytes) -> str:
    """A strong entity tag of a representation's bytes."""
    return '"' + hashlib.sha256(body).hexdigest()[:32] + '"'


def etag_matches(if_none_match: str | None, etag: str) -> bool:
    """Whether an ``If-None-Match`` header names ``etag`` (weak comparison, as RFC 9110 has for GET)."""
    if not if_none_match:
        return False
    tags = [t.strip() for t in if_none_match.split(",")]
    return "*" in tags or etag in (t.removeprefix("W/") for t in tags)


__all__ = [
    "callback_view",
    "etag_matches",
    "etag_of",
    "excitation_json",
    "job_summary_view",
    "job_view",
    "result_summary",
    "served_result",
]
