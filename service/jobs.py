"""Job creation, results, listing and deletion (the logic behind the ``/v1/jobs`` routes; how a job is
shown is :mod:`service.views`)."""

from __future__ import annotations

import hashlib
import logging
import time
from collections.abc import Sequence
from typing import Any

from api_schemas import AnalysisResult, ForceLog, JobCreate, JobList
from backend.errors import InvalidInputError, NotFoundError
from backend.store import ClipRecord, JobRecord, NewJob, dumps_canonical
from service.context import ServiceContext
from service.retention import expiry
from service.views import excitation_json, job_summary_view, served_result
from service.webhooks import check_callback_url

log = logging.getLogger(__name__)


def job_result(ctx: ServiceContext, job_id: str, *, tenant: str, root_path: str = "") -> AnalysisResult:
    """A succeeded job's result (its artifacts as URLs); 404 ``result-not-found`` before it has one."""
    job = ctx.store.get_job(job_id, tenant)
    served = served_result(job, root_path) if job.status == "succeeded" else None
    if served is None:
        raise NotFoundError(
            f"job {job_id} is {job.status}; its result exists once it has succeeded (GET /v1/jobs/{job_id}"
            "?wait=60 waits for that)",
            code="result-not-found",
        )
    return AnalysisResult.model_validate(served)


def _invalid(loc: Sequence[str], msg: str) -> InvalidInputError:
    return InvalidInputError(
        f"{'.'.join(loc[1:])}: {msg}",
        code="invalid-parameter",
        errors=[{"loc": list(loc), "msg": msg, "type": "value_error"}],
    )


def check_against_clip(body: JobCreate, clip: ClipRecord) -> None:
    """Reject parameters that cannot work with this clip, before a worker spends time on it."""
    p = body.parameters
    info = clip.info
    frames = int(info.get("frames") or 0)
    fps = p.fps if p.fps is not None else info.get("fps")
    if fps is None:
        raise _invalid(
            ("body", "parameters", "fps"),
            f"clip {clip.id} carries no frame rate; give the recording rate in parameters.fps (Hz)",
        )
    if p.min_frequency_hz is not None and p.min_frequency_hz >= float(fps) / 2:
        raise _invalid(
            ("body", "parameters", "min_frequency_hz"),
            f"min_frequency_hz={p.min_frequency_hz} is at or above the Nyquist frequency "
            f"{float(fps) / 2:g} Hz of a {float(fps):g} fps clip",
        )
    start = p.start_frame or 0
    if frames and start >= frames:
        raise _invalid(
            ("body", "parameters", "start_frame"), f"start_frame={start} is past the clip's {frames} frames"
        )
    if frames and p.frames is not None and start + p.frames > frames:
        raise _invalid(
            ("body", "parameters", "frames"),
            f"a window of {p.frames} frames from frame {start} does not fit the clip's {frames} frames",
        )
    if body.force_log is not None and frames:
        # A rate given in the request rescales the frames' times: their span is then frames / that rate.
        duration = info.get("duration_s") if p.fps is None else None
        _check_force_log_clock(body.force_log, frames=frames, fps=float(fps), duration_s=duration)


def _check_force_log_clock(log: ForceLog, *, frames: int, fps: float, duration_s: Any) -> None:
    """Refuse a force log on another clock than the clip's: its times (``offset_s`` added) must overlap
    the frames' (0 at the first frame; a frame's time of slack at the end)."""
    last = float(duration_s) if isinstance(duration_s, int | float) and duration_s > 0 else (frames - 1) / fps
    start, end = log.time_s[0] + log.offset_s, log.time_s[-1] + log.offset_s
    if end >= 0.0 and start <= last + 1.0 / fps:
        return
    raise _invalid(
        ("body", "force_log", "offset_s"),
        f"the force log's times ({start:.6g} s to {end:.6g} s once offset_s={log.offset_s:g} is added) do "
        f"not overlap the clip's frames (0 s to {last:.6g} s); its clock is not the clip's: set offset_s to "
        "minus the log's time at the clip's first frame",
    )


def request_hash(body: JobCreate) -> str:
    doc = body.model_dump(mode="json")
    if doc.get("force_log") is None:  # a request without one hashes as it did before the field existed
        doc.pop("force_log", None)
    return hashlib.sha256(dumps_canonical(doc).encode()).hexdigest()


def create_job(
    ctx: ServiceContext, body: JobCreate, *, tenant: str, idempotency_key: str | None
) -> tuple[JobRecord, bool]:
    """Validate against the clip, insert the job and publish it. Returns ``(job, created)``.

    The clip must be ``tenant``'s (another key's clip is reported as missing); a key at its limit of
    active jobs gets 429.
    """
    digest = request_hash(body)
    if idempotency_key is not None:
        existing = ctx.store.job_by_idempotency_key(idempotency_key, digest, tenant)
        if existing is not None:
            return existing, False
    clip = ctx.store.find_clip(body.clip_id, tenant)
    if clip is None:
        raise InvalidInputError(
            f"clip {body.clip_id!r} does not exist (never uploaded, or deleted); "
            "upload it with POST /v1/clips and use the returned id",
            code="unknown-clip",
            errors=[{"loc": ["body", "clip_id"], "msg": "no such clip", "type": "value_error"}],
        )
    check_against_clip(body, clip)
    if body.callback_url is not None:
        check_callback_url(body.callback_url, ctx.settings)
    force_log = body.force_log
    new = NewJob(
        clip_id=body.clip_id,
        excitation=excitation_json(body.excitation),
        parameters=body.parameters.model_dump(mode="json", exclude_none=True),
        force_log=None if force_log is None else force_log.model_dump(mode="json"),
        force_log_summary=None if force_log is None else force_log.summary().model_dump(mode="json"),
        owner=tenant,
        expires_at=expiry(time.time(), ctx.settings.retention_s),
        callback_url=body.callback_url,
        idempotency_key=idempotency_key,
        request_hash=digest,
    )
    job, created = ctx.store.create_job(new, limits=ctx.tenant_limits)
    if created:
        ctx.metrics.jobs_created.inc()
        ctx.publish(job.id)
        log.info("job %s: queued for clip %s", job.id, job.clip_id)
    return job, created


def list_jobs(
    ctx: ServiceContext,
    *,
    tenant: str,
    statuses: Sequence[str],
    clip_id: str | None,
    limit: int,
    cursor: str | None,
    root_path: str = "",
) -> JobList:
    jobs, next_cursor = ctx.store.list_jobs(
        statuses=statuses, clip_id=clip_id, limit=limit, cursor=cursor, owner=tenant
    )
    return JobList(items=[job_summary_view(j, root_path=root_path) for j in jobs], next_cursor=next_cursor)


def artifact_file(ctx: ServiceContext, job_id: str, name: str, *, tenant: str) -> Any:
    """The path of a finished job's artifact (only names the result lists, plus ``result.json``)."""
    job = ctx.store.get_job(job_id, tenant)
    if job.status != "succeeded" or job.result is None:
        raise NotFoundError(
            f"job {job_id} is {job.status}; artifacts exist once it has succeeded", code="artifact-not-found"
        )
    artifacts = job.result.get("artifacts") or {}
    names = {v for v in artifacts.values() if isinstance(v, str)} | {"result.json"}
    if name not in names:
        raise NotFoundError(
            f"job {job_id} has no artifact {name!r}; it has {', '.join(sorted(names))}",
            code="artifact-not-found",
        )
    return ctx.storage.artifact_path(job_id, name)


def delete_job(ctx: ServiceContext, job_id: str, tenant: str) -> None:
    """Delete one of ``tenant``'s jobs and its artifacts (an active job is cancelled first)."""
    ctx.store.delete_job(job_id, tenant)
    ctx.storage.delete_job_outputs(job_id)
    log.info("job %s: deleted", job_id)
