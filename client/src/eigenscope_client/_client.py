"""The clients: :class:`Client` (blocking) and :class:`AsyncClient` (asyncio or trio), one method per API
operation plus :meth:`~Client.wait`, :meth:`~Client.analyze` and :meth:`~Client.download_artifact`.

Both build their requests and read their answers with the same code (:class:`_Protocol`); only sending
differs. Every request is safe to retry: uploads and job creations carry an ``Idempotency-Key`` (made up
when the caller gives none), the rest are reads, cancels and deletes. A request is retried, up to
``max_retries`` times, when the connection fails, on 502/504, and on 429/503 after the server's
``Retry-After``.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
import time
import uuid
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import httpx

from eigenscope_client._errors import TransportError, WaitTimeoutError, error_for
from eigenscope_client._force_log import ForceLog
from eigenscope_client._models import (
    AnalysisParameters,
    AnalysisResult,
    Clip,
    Excitation,
    Job,
    JobStatus,
    JobSummary,
    Page,
    Stream,
)
from eigenscope_client._upload import ProgressCallback, UploadBody
from eigenscope_client._version import __version__

T = TypeVar("T")

DEFAULT_BASE_URL = "http://127.0.0.1:8000"
#: The server's cap on one long-poll; a longer wait is made of several.
LONG_POLL_S = 60.0
#: Longest ``Retry-After`` honoured before a retry, seconds.
MAX_RETRY_WAIT_S = 60.0
#: Spec operation id -> the method of both clients that performs it (a test keeps this complete).
OPERATIONS = {
    "create_clip": "upload_clip",
    "list_clips": "list_clips",
    "get_clip": "get_clip",
    "delete_clip": "delete_clip",
    "create_job": "create_job",
    "list_jobs": "list_jobs",
    "get_job": "get_job",
    "delete_job": "delete_job",
    "cancel_job": "cancel_job",
    "get_job_result": "get_result",
    "get_job_artifact": "download_artifact",
    "create_stream": "create_stream",
    "list_streams": "list_streams",
    "get_stream": "get_stream",
    "healthz": "health",
    "readyz": "ready",
    "metrics": "metrics",
}
JobProgress = Callable[[Job], None]


@dataclass
class _Call:
    """One API request, before it is sent."""

    method: str
    path: str
    params: dict[str, Any] | None = None
    json: Any = None
    headers: dict[str, str] = field(default_factory=dict)
    upload: UploadBody | None = None
    timeout: float | None = None
    #: Statuses that are answers, not errors (every 2xx, and these).
    accept: tuple[int, ...] = ()


def _excitation_json(excitation: Excitation | list[Excitation] | dict[str, Any] | None) -> Any:
    if excitation is None or isinstance(excitation, dict):
        return excitation
    if isinstance(excitation, list):
        return [e if isinstance(e, dict) else e.to_dict() for e in excitation]
    return excitation.to_dict()


def _artifact_path(job: Job | str, name: str) -> str:
    """The URL path of artifact ``name`` (a file name, or a key of ``result.artifacts``) of ``job``."""
    if isinstance(job, Job) and job.result is not None:
        url = job.result.artifacts.get(name)
        if url is not None and "/v1/" in url:
            return url[url.index("/v1/") :]
    job_id = job.id if isinstance(job, Job) else job
    # A key names its file: ``result`` is result.json, the images are PNGs.
    filename = name if "." in name else ("result.json" if name == "result" else f"{name}.png")
    return f"/v1/jobs/{job_id}/artifacts/{filename}"


def _retry_after(response: httpx.Response) -> float | None:
    value = response.headers.get("retry-after", "").strip()
    try:
        return max(float(value), 0.0) if value else None
    except ValueError:
        return None


class _Protocol:
    """What both clients share: configuration, the requests of each operation and reading the answers."""

    def __init__(
        self,
        base_url: str | None,
        *,
        api_key: str | None,
        timeout: float,
        max_retries: int,
    ) -> None:
        base = (base_url or os.environ.get("EIGENSCOPE_URL") or DEFAULT_BASE_URL).rstrip("/")
        if not base.startswith(("http://", "https://")):
            raise ValueError(f"base_url {base!r} must be an http:// or https:// URL")
        self.base_url = base
        self.api_key = api_key if api_key is not None else (os.environ.get("EIGENSCOPE_API_KEY") or None)
        self.timeout = timeout
        self.max_retries = max_retries

    def _default_headers(self) -> dict[str, str]:
        headers = {"User-Agent": f"eigenscope-client/{__version__}", "Accept": "application/json"}
        if self.api_key:
            headers["Authorization"] = f"Bearer {self.api_key}"
        return headers

    def _request_kwargs(self, call: _Call) -> dict[str, Any]:
        headers = {"X-Request-ID": uuid.uuid4().hex, **call.headers}
        timeout = httpx.Timeout(call.timeout or self.timeout, connect=min(self.timeout, 10.0))
        return {"params": call.params, "json": call.json, "headers": headers, "timeout": timeout}

    def _retry_delay(self, attempt: int, response: httpx.Response | None) -> float | None:
        """Seconds before retry number ``attempt + 1``, or None when the outcome is final."""
        if attempt >= self.max_retries:
            return None
        backoff = float(min(0.5 * 2**attempt, 8.0))
        if response is None:
            return backoff
        if response.status_code in (429, 503):
            wait = _retry_after(response)
            return float(min(wait if wait is not None else backoff, MAX_RETRY_WAIT_S))
        if response.status_code in (502, 504):
            return backoff
        return None

    @staticmethod
    def _raise_for(response: httpx.Response, call: _Call) -> None:
        status = response.status_code
        if status < 400 or status in call.accept:
            return
        try:
            doc = response.json()
        except ValueError:
            doc = None
        if not isinstance(doc, dict):
            doc = {
                "title": response.reason_phrase or "Error",
                "status": status,
                "detail": response.text[:500],
            }
        raise error_for(
            status,
            doc,
            request_id=response.headers.get("x-request-id"),
            retry_after=_retry_after(response),
        )

    # Requests of each operation ------------------------------------------------------------------

    @staticmethod
    def _upload_call(
        path: str | os.PathLike[str],
        *,
        idempotency_key: str | None,
        progress: ProgressCallback | None,
        filename: str | None,
        timeout: float | None,
    ) -> _Call:
        body = UploadBody.of(path, filename=filename, progress=progress)
        headers = {**body.headers(), "Idempotency-Key": idempotency_key or uuid.uuid4().hex}
        return _Call("POST", "/v1/clips", headers=headers, upload=body, timeout=timeout)

    @staticmethod
    def _create_job_call(
        clip_id: str,
        *,
        excitation: Excitation | list[Excitation] | dict[str, Any] | None,
        parameters: AnalysisParameters | dict[str, Any] | None,
        callback_url: str | None,
        idempotency_key: str | None,
        force_log: ForceLog | dict[str, Any] | None = None,
    ) -> _Call:
        body: dict[str, Any] = {"clip_id": clip_id}
        if excitation is not None:
            body["excitation"] = _excitation_json(excitation)
        if parameters:
            body["parameters"] = dict(parameters)
        if force_log is not None:
            body["force_log"] = force_log.to_dict() if isinstance(force_log, ForceLog) else force_log
        if callback_url is not None:
            body["callback_url"] = callback_url
        headers = {"Idempotency-Key": idempotency_key or uuid.uuid4().hex}
        return _Call("POST", "/v1/jobs", json=body, headers=headers)

    def _get_job_call(self, job_id: str, *, wait: float | None, etag: str | None) -> _Call:
        params = {"wait": f"{wait:g}"} if wait is not None else None
        headers = {"If-None-Match": etag} if etag else {}
        timeout = None if wait is None else max(self.timeout, wait + 15.0)
        return _Call(
            "GET", f"/v1/jobs/{job_id}", params=params, headers=headers, timeout=timeout, accept=(304,)
        )

    @staticmethod
    def _list_jobs_call(
        *, status: JobStatus | list[JobStatus] | None, clip_id: str | None, limit: int, cursor: str | None
    ) -> _Call:
        params: dict[str, Any] = {"limit": limit}
        if status is not None:
            params["status"] = [status] if isinstance(status, str) else list(status)
        if clip_id is not None:
            params["clip_id"] = clip_id
        if cursor is not None:
            params["cursor"] = cursor
        return _Call("GET", "/v1/jobs", params=params)

    @staticmethod
    def _list_clips_call(*, limit: int, cursor: str | None) -> _Call:
        params: dict[str, Any] = {"limit": limit}
        if cursor is not None:
            params["cursor"] = cursor
        return _Call("GET", "/v1/clips", params=params)

    @staticmethod
    def _create_stream_call(
        *,
        width: int | None,
        height: int | None,
        excitation: Excitation | list[Excitation] | dict[str, Any] | None,
        parameters: AnalysisParameters | dict[str, Any] | None,
        target_relative_uncertainty: float,
        max_duration_s: float,
    ) -> _Call:
        body: dict[str, Any] = {
            "target_relative_uncertainty": target_relative_uncertainty,
            "max_duration_s": max_duration_s,
        }
        if width is not None and height is not None:
            body["width"], body["height"] = width, height
        if excitation is not None:
            body["excitation"] = _excitation_json(excitation)
        if parameters:
            body["parameters"] = dict(parameters)
        return _Call("POST", "/v1/streams", json=body)

    @staticmethod
    def _list_streams_call(*, active: bool, limit: int) -> _Call:
        return _Call("GET", "/v1/streams", params={"active": str(active).lower(), "limit": limit})

    # Reading answers ------------------------------------------------------------------------------

    @staticmethod
    def _job(response: httpx.Response) -> Job:
        job: Job = Job.from_dict(response.json())
        etag = response.headers.get("etag")
        return dataclasses.replace(job, etag=etag) if etag else job

    @staticmethod
    def _page(response: httpx.Response, item: Callable[[dict[str, Any]], T]) -> Page[T]:
        doc = response.json()
        return Page([item(x) for x in doc.get("items", [])], doc.get("next_cursor"))


@dataclass
class _Waiter:
    """The long-poll loop of ``wait``, shared by both clients: the next request, and what its answer means."""

    protocol: _Protocol
    current: Job
    deadline: float | None
    poll_s: float
    on_progress: JobProgress | None
    asked_s: float = 0.0
    started: float = 0.0

    @classmethod
    def begin(
        cls,
        protocol: _Protocol,
        job: Job,
        timeout: float | None,
        poll_s: float,
        on_progress: JobProgress | None,
    ) -> _Waiter:
        if on_progress is not None:
            on_progress(job)
        deadline = None if timeout is None else time.monotonic() + timeout
        return cls(protocol, job, deadline, poll_s, on_progress)

    def next_call(self) -> _Call:
        """The next long-poll (``If-None-Match`` when progress is followed, so any change answers)."""
        self.asked_s = self.poll_s
        if self.deadline is not None:
            left = self.deadline - time.monotonic()
            if left <= 0:
                raise WaitTimeoutError(
                    f"job {self.current.id} still {self.current.status} when the wait ran out", self.current
                )
            self.asked_s = min(self.poll_s, left)
        self.started = time.monotonic()
        etag = self.current.etag if self.on_progress is not None else None
        return self.protocol._get_job_call(self.current.id, wait=self.asked_s, etag=etag)

    def take(self, response: httpx.Response) -> float:
        """Read a long-poll's answer; returns the seconds to pause before the next one.

        An answer that came back unchanged and unfinished well before its wait is from a server that does
        not long-poll: the pause is then its Retry-After, rather than asking again at once.
        """
        if response.status_code == 304:
            return 0.0
        latest = _Protocol._job(response)
        early = time.monotonic() - self.started < self.asked_s / 2
        pause = (
            (_retry_after(response) or 1.0)
            if early and not latest.done and latest.etag == self.current.etag
            else 0.0
        )
        if self.on_progress is not None and latest.etag != self.current.etag:
            self.on_progress(latest)
        self.current = latest
        return pause


class Client(_Protocol):
    """A blocking client of an Eigenscope server.

    Parameters
    ----------
    base_url : str, optional
        The server, e.g. ``http://10.0.0.5:8000`` (default: ``EIGENSCOPE_URL`` or ``http://127.0.0.1:8000``).
    api_key : str, optional
        Sent as ``Authorization: Bearer <key>`` (default: ``EIGENSCOPE_API_KEY``; none for an open server).
    timeout : float
        Seconds a request may take (uploads and long-polls get longer).
    max_retries : int
        Retries of a request after a connection failure, 502/504, or 429/503 (after ``Retry-After``).
    http_client : httpx.Client, optional
        Your own (proxies, TLS settings); the client does not close it.
    """

    def __init__(
        self,
        base_url: str | None = None,
        *,
        api_key: str | None = None,
        timeout: float = 60.0,
        max_retries: int = 3,
        http_client: httpx.Client | None = None,
    ) -> None:
        super().__init__(base_url, api_key=api_key, timeout=timeout, max_retries=max_retries)
        self._owns_http = http_client is None
        self._http = http_client or httpx.Client()

    def close(self) -> None:
        if self._owns_http:
            self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _send(self, call: _Call, *, stream: bool = False) -> httpx.Response:
        attempt = 0
        while True:
            kwargs = self._request_kwargs(call)
            headers = {**self._default_headers(), **kwargs.pop("headers")}
            content: Iterator[bytes] | None = call.upload.chunks() if call.upload is not None else None
            try:
                request = self._http.build_request(
                    call.method, self.base_url + call.path, content=content, headers=headers, **kwargs
                )
                response = self._http.send(request, stream=stream)
            except httpx.TransportError as exc:
                delay = self._retry_delay(attempt, None)
                if delay is None:
                    raise TransportError(f"{call.method} {self.base_url}{call.path} failed: {exc}") from exc
            else:
                delay = self._retry_delay(attempt, response) if response.status_code >= 400 else None
                if delay is None:
                    if stream and response.status_code >= 400:
                        response.read()
                    self._raise_for(response, call)
                    return response
                response.close()
            time.sleep(delay)
            attempt += 1

    # Clips ---------------------------------------------------------------------------------------

    def upload_clip(
        self,
        path: str | os.PathLike[str],
        *,
        progress: ProgressCallback | None = None,
        idempotency_key: str | None = None,
        filename: str | None = None,
    ) -> Clip:
        """Upload a clip file; ``progress(sent_bytes, total_bytes)`` follows the upload."""
        call = self._upload_call(
            path, idempotency_key=idempotency_key, progress=progress, filename=filename, timeout=None
        )
        clip: Clip = Clip.from_dict(self._send(call).json())
        return clip

    def get_clip(self, clip_id: str) -> Clip:
        clip: Clip = Clip.from_dict(self._send(_Call("GET", f"/v1/clips/{clip_id}")).json())
        return clip

    def list_clips(self, *, limit: int = 20, cursor: str | None = None) -> Page[Clip]:
        """One page of clips, newest first."""
        return self._page(self._send(self._list_clips_call(limit=limit, cursor=cursor)), Clip.from_dict)

    def iter_clips(self, *, page_size: int = 50) -> Iterator[Clip]:
        """Every clip, newest first, fetched a page at a time."""
        cursor: str | None = None
        while True:
            page = self.list_clips(limit=page_size, cursor=cursor)
            yield from page.items
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    def delete_clip(self, clip_id: str) -> None:
        self._send(_Call("DELETE", f"/v1/clips/{clip_id}"))

    # Jobs ----------------------------------------------------------------------------------------

    def create_job(
        self,
        clip_id: str,
        *,
        excitation: Excitation | list[Excitation] | dict[str, Any] | None = None,
        parameters: AnalysisParameters | dict[str, Any] | None = None,
        callback_url: str | None = None,
        idempotency_key: str | None = None,
        force_log: ForceLog | dict[str, Any] | None = None,
    ) -> Job:
        """Queue an analysis of an uploaded clip. ``force_log``: the robot's force sensor recorded beside
        the clip (:class:`ForceLog`, e.g. ``ForceLog.from_file("push.csv")``), whose push, hold and
        release or strike is the excitation (a typed ``excitation`` overrides it)."""
        call = self._create_job_call(
            clip_id,
            excitation=excitation,
            parameters=parameters,
            callback_url=callback_url,
            idempotency_key=idempotency_key,
            force_log=force_log,
        )
        return self._job(self._send(call))

    def get_job(self, job_id: str, *, wait: float | None = None) -> Job:
        """The job; with ``wait`` (seconds) the server answers once it has ended or the wait ran out."""
        return self._job(self._send(self._get_job_call(job_id, wait=wait, etag=None)))

    def get_result(self, job: Job | JobSummary | str) -> AnalysisResult:
        """A succeeded job's result alone (what a job list's ``result_url`` names)."""
        job_id = job if isinstance(job, str) else job.id
        result: AnalysisResult = AnalysisResult.from_dict(
            self._send(_Call("GET", f"/v1/jobs/{job_id}/result")).json()
        )
        return result

    def create_stream(
        self,
        *,
        width: int | None = None,
        height: int | None = None,
        excitation: Excitation | list[Excitation] | dict[str, Any] | None = None,
        parameters: AnalysisParameters | dict[str, Any] | None = None,
        target_relative_uncertainty: float = 0.01,
        max_duration_s: float = 60.0,
    ) -> Stream:
        """Open a live stream session; send frames over its ``websocket_url`` (or use
        :class:`~eigenscope_client.StreamSession`, which does both)."""
        call = self._create_stream_call(
            width=width,
            height=height,
            excitation=excitation,
            parameters=parameters,
            target_relative_uncertainty=target_relative_uncertainty,
            max_duration_s=max_duration_s,
        )
        stream: Stream = Stream.from_dict(self._send(call).json())
        return stream

    def get_stream(self, stream_id: str) -> Stream:
        stream: Stream = Stream.from_dict(self._send(_Call("GET", f"/v1/streams/{stream_id}")).json())
        return stream

    def list_streams(self, *, active: bool = False, limit: int = 20) -> list[Stream]:
        """Streams newest first (only those not ended with ``active``)."""
        doc = self._send(self._list_streams_call(active=active, limit=limit)).json()
        return [Stream.from_dict(x) for x in doc.get("items", [])]

    def wait_for_change(self, job: Job, *, timeout: float = LONG_POLL_S) -> Job:
        """``job`` as it is once it differs from the one given (progress, stage, end), or after ``timeout``
        seconds (then the same job)."""
        response = self._send(self._get_job_call(job.id, wait=min(timeout, LONG_POLL_S), etag=job.etag))
        return job if response.status_code == 304 else self._job(response)

    def wait(
        self,
        job: Job | str,
        *,
        timeout: float | None = None,
        on_progress: JobProgress | None = None,
        poll_s: float = LONG_POLL_S,
    ) -> Job:
        """Long-poll until the job has ended; ``on_progress(job)`` is called on every change.

        Raises :class:`WaitTimeoutError` when ``timeout`` seconds pass first. The job is returned whatever its
        end: call :meth:`Job.raise_for_status` to turn a failure into an exception.
        """
        first = self.get_job(job if isinstance(job, str) else job.id)
        waiter = _Waiter.begin(self, first, timeout, poll_s, on_progress)
        while not waiter.current.done:
            pause = waiter.take(self._send(waiter.next_call()))
            if pause:
                time.sleep(pause)
        return waiter.current

    def list_jobs(
        self,
        *,
        status: JobStatus | list[JobStatus] | None = None,
        clip_id: str | None = None,
        limit: int = 20,
        cursor: str | None = None,
    ) -> Page[JobSummary]:
        """One page of jobs, newest first, optionally of some states or one clip: summaries (each with
        its result's headline; :meth:`get_job` gives a job with its whole result)."""
        call = self._list_jobs_call(status=status, clip_id=clip_id, limit=limit, cursor=cursor)
        return self._page(self._send(call), JobSummary.from_dict)

    def iter_jobs(
        self, *, status: JobStatus | list[JobStatus] | None = None, page_size: int = 50
    ) -> Iterator[JobSummary]:
        cursor: str | None = None
        while True:
            page = self.list_jobs(status=status, limit=page_size, cursor=cursor)
            yield from page.items
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    def cancel_job(self, job_id: str) -> Job:
        return self._job(self._send(_Call("POST", f"/v1/jobs/{job_id}/cancel")))

    def delete_job(self, job_id: str) -> None:
        """Delete a job and its artifacts (a running one is cancelled first)."""
        self._send(_Call("DELETE", f"/v1/jobs/{job_id}"))

    def download_artifact(
        self, job: Job | str, name: str, dest: str | os.PathLike[str] | None = None
    ) -> bytes | Path:
        """An artifact of a finished job: ``name`` is a file name (``mask.png``, ``result.json``) or a key
        of ``job.result.artifacts`` (``mask``, ``overlay`` ...). With ``dest`` (a file or a folder) it is
        streamed to disk and its path returned; else its bytes."""
        call = _Call("GET", _artifact_path(job, name), headers={"Accept": "*/*"})
        if dest is None:
            return self._send(call).content
        response = self._send(call, stream=True)
        try:
            return _save(response.iter_bytes(), Path(dest), call.path.rsplit("/", 1)[-1])
        finally:
            response.close()

    def analyze(
        self,
        path: str | os.PathLike[str],
        *,
        excitation: Excitation | list[Excitation] | dict[str, Any] | None = None,
        parameters: AnalysisParameters | dict[str, Any] | None = None,
        timeout: float | None = None,
        progress: ProgressCallback | None = None,
        on_progress: JobProgress | None = None,
        force_log: ForceLog | dict[str, Any] | None = None,
    ) -> Job:
        """Upload a clip, queue its analysis and wait for the end: the one call a robot needs."""
        clip = self.upload_clip(path, progress=progress)
        job = self.create_job(clip.id, excitation=excitation, parameters=parameters, force_log=force_log)
        return self.wait(job, timeout=timeout, on_progress=on_progress)

    # Health --------------------------------------------------------------------------------------

    def health(self) -> dict[str, Any]:
        doc: dict[str, Any] = self._send(_Call("GET", "/healthz")).json()
        return doc

    def ready(self) -> dict[str, Any]:
        """The server's readiness checks; :class:`ServiceUnavailableError` while a part is down."""
        doc: dict[str, Any] = self._send(_Call("GET", "/readyz")).json()
        return doc

    def metrics(self) -> str:
        """The Prometheus metrics text."""
        return self._send(_Call("GET", "/metrics", headers={"Accept": "text/plain"})).text


class AsyncClient(_Protocol):
    """:class:`Client` for ``async`` code: the same methods, awaited. Use ``async with AsyncClient(...)``."""

    def __init__(
        self,
        base_url: str | None = None,
        *,
        api_key: str | None = None,
        timeout: float = 60.0,
        max_retries: int = 3,
        http_client: httpx.AsyncClient | None = None,
    ) -> None:
        super().__init__(base_url, api_key=api_key, timeout=timeout, max_retries=max_retries)
        self._owns_http = http_client is None
        self._http = http_client or httpx.AsyncClient()

    async def aclose(self) -> None:
        if self._owns_http:
            await self._http.aclose()

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def _send(self, call: _Call, *, stream: bool = False) -> httpx.Response:
        import anyio

        attempt = 0
        while True:
            kwargs = self._request_kwargs(call)
            headers = {**self._default_headers(), **kwargs.pop("headers")}
            content: AsyncIterator[bytes] | None = call.upload.achunks() if call.upload is not None else None
            try:
                request = self._http.build_request(
                    call.method, self.base_url + call.path, content=content, headers=headers, **kwargs
                )
                response = await self._http.send(request, stream=stream)
            except httpx.TransportError as exc:
                delay = self._retry_delay(attempt, None)
                if delay is None:
                    raise TransportError(f"{call.method} {self.base_url}{call.path} failed: {exc}") from exc
            else:
                delay = self._retry_delay(attempt, response) if response.status_code >= 400 else None
                if delay is None:
                    if stream and response.status_code >= 400:
                        await response.aread()
                    self._raise_for(response, call)
                    return response
                await response.aclose()
            await anyio.sleep(delay)
            attempt += 1

    async def upload_clip(
        self,
        path: str | os.PathLike[str],
        *,
        progress: ProgressCallback | None = None,
        idempotency_key: str | None = None,
        filename: str | None = None,
    ) -> Clip:
        call = self._upload_call(
            path, idempotency_key=idempotency_key, progress=progress, filename=filename, timeout=None
        )
        clip: Clip = Clip.from_dict((await self._send(call)).json())
        return clip

    async def get_clip(self, clip_id: str) -> Clip:
        clip: Clip = Clip.from_dict((await self._send(_Call("GET", f"/v1/clips/{clip_id}"))).json())
        return clip

    async def list_clips(self, *, limit: int = 20, cursor: str | None = None) -> Page[Clip]:
        return self._page(await self._send(self._list_clips_call(limit=limit, cursor=cursor)), Clip.from_dict)

    async def iter_clips(self, *, page_size: int = 50) -> AsyncIterator[Clip]:
        cursor: str | None = None
        while True:
            page = await self.list_clips(limit=page_size, cursor=cursor)
            for clip in page.items:
                yield clip
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    async def delete_clip(self, clip_id: str) -> None:
        await self._send(_Call("DELETE", f"/v1/clips/{clip_id}"))

    async def create_job(
        self,
        clip_id: str,
        *,
        excitation: Excitation | list[Excitation] | dict[str, Any] | None = None,
        parameters: AnalysisParameters | dict[str, Any] | None = None,
        callback_url: str | None = None,
        idempotency_key: str | None = None,
        force_log: ForceLog | dict[str, Any] | None = None,
    ) -> Job:
        call = self._create_job_call(
            clip_id,
            excitation=excitation,
            parameters=parameters,
            callback_url=callback_url,
            idempotency_key=idempotency_key,
            force_log=force_log,
        )
        return self._job(await self._send(call))

    async def get_job(self, job_id: str, *, wait: float | None = None) -> Job:
        return self._job(await self._send(self._get_job_call(job_id, wait=wait, etag=None)))

    async def get_result(self, job: Job | JobSummary | str) -> AnalysisResult:
        job_id = job if isinstance(job, str) else job.id
        response = await self._send(_Call("GET", f"/v1/jobs/{job_id}/result"))
        result: AnalysisResult = AnalysisResult.from_dict(response.json())
        return result

    async def create_stream(
        self,
        *,
        width: int | None = None,
        height: int | None = None,
        excitation: Excitation | list[Excitation] | dict[str, Any] | None = None,
        parameters: AnalysisParameters | dict[str, Any] | None = None,
        target_relative_uncertainty: float = 0.01,
        max_duration_s: float = 60.0,
    ) -> Stream:
        call = self._create_stream_call(
            width=width,
            height=height,
            excitation=excitation,
            parameters=parameters,
            target_relative_uncertainty=target_relative_uncertainty,
            max_duration_s=max_duration_s,
        )
        stream: Stream = Stream.from_dict((await self._send(call)).json())
        return stream

    async def get_stream(self, stream_id: str) -> Stream:
        stream: Stream = Stream.from_dict((await self._send(_Call("GET", f"/v1/streams/{stream_id}"))).json())
        return stream

    async def list_streams(self, *, active: bool = False, limit: int = 20) -> list[Stream]:
        doc = (await self._send(self._list_streams_call(active=active, limit=limit))).json()
        return [Stream.from_dict(x) for x in doc.get("items", [])]

    async def wait_for_change(self, job: Job, *, timeout: float = LONG_POLL_S) -> Job:
        response = await self._send(self._get_job_call(job.id, wait=min(timeout, LONG_POLL_S), etag=job.etag))
        return job if response.status_code == 304 else self._job(response)

    async def wait(
        self,
        job: Job | str,
        *,
        timeout: float | None = None,
        on_progress: JobProgress | None = None,
        poll_s: float = LONG_POLL_S,
    ) -> Job:
        import anyio

        first = await self.get_job(job if isinstance(job, str) else job.id)
        waiter = _Waiter.begin(self, first, timeout, poll_s, on_progress)
        while not waiter.current.done:
            pause = waiter.take(await self._send(waiter.next_call()))
            if pause:
                await anyio.sleep(pause)
        return waiter.current

    async def list_jobs(
        self,
        *,
        status: JobStatus | list[JobStatus] | None = None,
        clip_id: str | None = None,
        limit: int = 20,
        cursor: str | None = None,
    ) -> Page[JobSummary]:
        call = self._list_jobs_call(status=status, clip_id=clip_id, limit=limit, cursor=cursor)
        return self._page(await self._send(call), JobSummary.from_dict)

    async def iter_jobs(
        self, *, status: JobStatus | list[JobStatus] | None = None, page_size: int = 50
    ) -> AsyncIterator[JobSummary]:
        cursor: str | None = None
        while True:
            page = await self.list_jobs(status=status, limit=page_size, cursor=cursor)
            for job in page.items:
                yield job
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    async def cancel_job(self, job_id: str) -> Job:
        return self._job(await self._send(_Call("POST", f"/v1/jobs/{job_id}/cancel")))

    async def delete_job(self, job_id: str) -> None:
        await self._send(_Call("DELETE", f"/v1/jobs/{job_id}"))

    async def download_artifact(
        self, job: Job | str, name: str, dest: str | os.PathLike[str] | None = None
    ) -> bytes | Path:
        call = _Call("GET", _artifact_path(job, name), headers={"Accept": "*/*"})
        response = await self._send(call)
        if dest is None:
            return response.content
        return _save(iter([response.content]), Path(dest), call.path.rsplit("/", 1)[-1])

    async def analyze(
        self,
        path: str | os.PathLike[str],
        *,
        excitation: Excitation | list[Excitation] | dict[str, Any] | None = None,
        parameters: AnalysisParameters | dict[str, Any] | None = None,
        timeout: float | None = None,
        progress: ProgressCallback | None = None,
        on_progress: JobProgress | None = None,
        force_log: ForceLog | dict[str, Any] | None = None,
    ) -> Job:
        clip = await self.upload_clip(path, progress=progress)
        job = await self.create_job(
            clip.id, excitation=excitation, parameters=parameters, force_log=force_log
        )
        return await self.wait(job, timeout=timeout, on_progress=on_progress)

    async def health(self) -> dict[str, Any]:
        doc: dict[str, Any] = (await self._send(_Call("GET", "/healthz"))).json()
        return doc

    async def ready(self) -> dict[str, Any]:
        doc: dict[str, Any] = (await self._send(_Call("GET", "/readyz"))).json()
        return doc

    async def metrics(self) -> str:
        return (await self._send(_Call("GET", "/metrics", headers={"Accept": "text/plain"}))).text


def _save(chunks: Iterator[bytes], dest: Path, filename: str) -> Path:
    """Write ``chunks`` to ``dest`` (or ``dest/filename`` for a folder) through a temporary file."""
    target = dest / filename if dest.is_dir() else dest
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.")
    try:
        with os.fdopen(fd, "wb") as fh:
            for chunk in chunks:
                fh.write(chunk)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target
