"""Service configuration from the environment (prefix ``EIGENSCOPE_``).

With nothing set, everything runs on this machine with no external server: the job store is a SQLite
file and the Celery broker is kombu's filesystem transport, both inside ``DATA_DIR``. Set
``EIGENSCOPE_REDIS_URL`` to scale workers out over Redis and ``EIGENSCOPE_DATABASE_URL`` to keep jobs in
PostgreSQL.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, Self

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from api_schemas.parameters import MAX_FORCE_NUMBER_BYTES, MAX_FORCE_SAMPLES

#: Name of the Celery queue every analysis job goes to.
DEFAULT_QUEUE = "eigenscope"
#: The default limits of request bodies, KiB: every route but the upload, and ``POST /v1/jobs``, whose
#: request may carry a force log of the most samples allowed (time and three components, each number at
#: full precision) beside the rest of a request.
DEFAULT_MAX_JSON_BODY_KB = 1024
_FORCE_LOG_KB = -(-MAX_FORCE_SAMPLES * 4 * MAX_FORCE_NUMBER_BYTES // 1024)  # rounded up
DEFAULT_MAX_JOB_BODY_KB = DEFAULT_MAX_JSON_BODY_KB + _FORCE_LOG_KB


class Settings(BaseSettings):
    """Every knob of the service and its workers; see the field descriptions."""

    model_config = SettingsConfigDict(env_prefix="EIGENSCOPE_", extra="ignore", frozen=True)

    redis_url: str | None = Field(
        default=None,
        description="Celery broker, e.g. redis://host:6379/0. Unset: embedded broker in DATA_DIR.",
    )
    database_url: str | None = Field(
        default=None,
        description="SQLAlchemy URL of the job store. Unset: SQLite file DATA_DIR/eigenscope.db.",
    )
    data_dir: Path = Field(default=Path("var"), description="Clips, artifacts and the embedded broker.")
    max_upload_mb: int = Field(default=2048, ge=1, description="Largest accepted upload, MiB.")
    queue: str = Field(default=DEFAULT_QUEUE, min_length=1)

    broker_polling_interval_s: float = Field(default=0.1, gt=0, le=10)
    task_soft_time_limit_s: float = Field(default=1800, gt=0)
    task_hard_time_limit_s: float = Field(default=1900, gt=0)
    visibility_timeout_s: float | None = Field(
        default=None, description="Redis visibility timeout; default: hard time limit + 10 min."
    )
    max_attempts: int = Field(default=3, ge=1, le=20, description="Runs of one job before it fails.")
    lease_s: float = Field(default=30, ge=2, description="A running job's lease; renewed every lease_s/3.")
    progress_interval_s: float = Field(default=0.25, ge=0, description="Least time between progress writes.")
    requeue_after_s: float = Field(
        default=3600, gt=0, description="Queued jobs this old are published again (lost-message insurance)."
    )
    sweep_interval_s: float = Field(default=5, gt=0, description="How often the API recovers stale jobs.")
    broker_reconcile_interval_s: float = Field(
        default=10,
        gt=0,
        description="How often the API compares the queued jobs with the messages Redis holds; a queued "
        "job without a message at two comparisons in a row (Redis lost them) is published again.",
    )

    probe_timeout_s: float = Field(default=120, gt=0, description="Upload validation time limit.")
    probe_memory_mb: int = Field(default=4096, ge=256, description="Address-space cap of the probe.")
    job_memory_mb: int = Field(
        default=6144,
        ge=0,
        description="Memory budget of one analysis, MiB: the address-space limit of the process that runs "
        "it (about twice its resident memory). A job over it fails once with `resources-exhausted` and is "
        "not retried (0: no budget).",
    )
    max_decoded_mb: int = Field(
        default=32768,
        ge=1,
        description="Most a clip may decompress to, MiB: its frames decoded (frames x width x height x "
        "bytes per pixel of its colour and depth streams, from what the file declares), and the entries "
        "of a zip archive (what a zipped ROS 2 bag unpacks to on disk) (413 `clip-too-large` beyond).",
    )
    max_inflation_ratio: float = Field(
        default=100.0,
        ge=2,
        description="Largest ratio of decompressed to compressed bytes of a zip archive or a deflated npz "
        "member, once it decompresses to more than INFLATION_FLOOR_MB (real footage deflates by a few; "
        "a decompression bomb by up to 1032).",
    )
    inflation_floor_mb: int = Field(
        default=256, ge=1, description="Archives decompressing to less than this are not ratio-checked, MiB."
    )
    background_niceness: int = Field(
        default=10,
        ge=0,
        le=19,
        description="CPU niceness of upload validation and of workers, so that the API's requests stay "
        "fast on a machine they share (0: same priority as the API).",
    )

    retry_after_s: int = Field(default=1, ge=1, description="Suggested polling interval for clients.")
    long_poll_max_s: float = Field(
        default=60, gt=0, le=600, description="Longest `GET /v1/jobs/{id}?wait=` a request may wait, seconds."
    )
    log_level: str = Field(default="INFO")
    log_format: Literal["text", "json"] = Field(
        default="text",
        description="`text` (one readable line per record) or `json` (one JSON object a line).",
    )
    worker_metrics_port: int | None = Field(
        default=None,
        ge=0,
        le=65535,
        description="Port on which each `eigenscope worker` serves its own Prometheus /metrics (unset or 0: "
        "none; `eigenscope serve` folds its worker's metrics into the API's /metrics).",
    )
    public_url: str | None = Field(
        default=None,
        max_length=512,
        description="The API's public base URL, e.g. https://eigenscope.example.org: artifact links in "
        "webhook payloads become absolute.",
    )

    # Webhooks ---------------------------------------------------------------------------------
    callback_hosts: str | None = Field(
        default=None,
        description="Comma-separated hosts a job's `callback_url` may name: `robot.lab`, `*.example.org`, "
        "`10.0.0.7:8080` (a port restricts to it). Unset: callbacks are refused.",
    )
    callback_secret: str | None = Field(
        default=None,
        repr=False,
        description="HMAC-SHA256 key that signs webhook deliveries (Standard Webhooks; `whsec_<base64>` or "
        "any string). Required with CALLBACK_HOSTS.",
    )
    callback_max_attempts: int = Field(default=8, ge=1, le=50, description="Deliveries tried per callback.")
    callback_retry_base_s: float = Field(
        default=2.0, gt=0, description="Delay before the first retry; doubled for each next one."
    )
    callback_retry_max_s: float = Field(default=600, gt=0, description="Longest delay between retries.")
    callback_timeout_s: float = Field(default=10, gt=0, le=120, description="Time limit of one delivery.")
    callback_poll_interval_s: float = Field(
        default=0.25, gt=0, le=60, description="How often the API looks for callbacks to deliver."
    )
    callback_concurrency: int = Field(
        default=8, ge=1, le=256, description="Callbacks one API process delivers at once."
    )
    callback_per_host: int = Field(
        default=2,
        ge=1,
        le=64,
        description="Of those, at most this many to one host: a receiver that hangs delays only its own.",
    )

    # Request bodies, connections and HTTP server limits ---------------------------------------
    max_json_body_kb: int = Field(
        default=DEFAULT_MAX_JSON_BODY_KB,
        ge=1,
        description="Largest body of every route but the clip upload and the job request, KiB (413 beyond; "
        "bodies declared larger are refused before they are read).",
    )
    max_job_body_kb: int = Field(
        default=DEFAULT_MAX_JOB_BODY_KB,
        ge=1,
        description="Largest body of a job request (POST /v1/jobs), KiB: by default room for a force log of "
        "the most samples allowed (200,000 of time and three components, about 20 MiB of JSON). 413 beyond.",
    )
    max_large_bodies_in_flight: int = Field(
        default=2,
        ge=1,
        description="Requests with bodies over EIGENSCOPE_MAX_JSON_BODY_KB (a job request carrying a force "
        "log) read and checked at once per API process: each takes several times its size in memory while "
        "it is parsed. 503 beyond, with Retry-After.",
    )
    body_idle_timeout_s: float = Field(
        default=30,
        gt=0,
        description="A request body (an upload included) that sends nothing for this long is dropped: "
        "408, the connection closed and any temporary file removed.",
    )
    max_uploads_in_flight: int = Field(
        default=32, ge=1, description="Uploads received at once per API process (503 beyond, Retry-After)."
    )
    http_timeout_keep_alive_s: int = Field(
        default=75,
        ge=1,
        description="Uvicorn: an idle keep-alive connection is closed after this. Longer than any "
        "client's or proxy's own idle expiry (httpx 5 s, nginx and cloud load balancers 60 s): a server "
        "that closes first races a client reusing the connection, which then sees a reset (ReadError) "
        "instead of an answer — a robot polling every 5 s would hit it.",
    )
    http_limit_concurrency: int = Field(
        default=512,
        ge=8,
        description="Uvicorn: connections and tasks at once per API process (503 beyond).",
    )
    http_backlog: int = Field(default=1024, ge=16, description="Uvicorn: pending connections queued.")
    http_max_header_kb: int = Field(
        default=16, ge=4, description="Uvicorn (h11): largest request line plus headers, KiB."
    )

    # Access, limits and retention -----------------------------------------------------------
    api_keys: str | None = Field(
        default=None,
        repr=False,
        description="Comma-separated API keys. With keys (here or in API_KEYS_FILE) every /v1 route needs "
        "`Authorization: Bearer <key>`; without any the service runs open.",
    )
    api_keys_file: Path | None = Field(
        default=None,
        description="File of API keys, one a line: the key itself or `sha256:<hex digest>`; `#` comments.",
    )
    allow_open_api: bool = Field(
        default=False,
        description="Let `eigenscope serve` listen on a non-loopback address without API keys (only "
        "behind a proxy that authenticates). Without it such a start is refused.",
    )
    published_host: str | None = Field(
        default=None,
        description="Address the API is reachable on from other machines when it differs from "
        "`--host` (a container's published port, see docker/compose.yaml); checked like `--host`.",
    )
    metrics_token: str | None = Field(
        default=None,
        repr=False,
        description="Bearer token `/metrics` requires. Unset: `/metrics` is open on a server without API "
        "keys and refused (401) on one with keys.",
    )
    auth_failures_per_window: int = Field(
        default=20,
        ge=1,
        description="Wrong API keys one client (IP address; see TRUSTED_PROXIES) may send per "
        "AUTH_FAILURE_WINDOW_S, over HTTP and stream WebSockets together; beyond, its requests get 429 "
        "with Retry-After until the window ends (but see AUTH_KNOWN_KEY_S).",
    )
    auth_failure_window_s: float = Field(default=60, gt=0, description="See AUTH_FAILURES_PER_WINDOW.")
    auth_known_key_s: float = Field(
        default=24 * 3600,
        ge=0,
        description="A key that authenticated from a client address within this long keeps working from "
        "it while that address is throttled for wrong keys (robots behind one NAT are not locked out by "
        "one that sends wrong keys); a key first seen from a throttled address waits (0: none is exempt).",
    )
    trusted_proxies: str | None = Field(
        default=None,
        description="Comma-separated addresses or networks of reverse proxies (`127.0.0.1`, "
        "`10.0.0.0/8`) whose `X-Forwarded-For` and `X-Forwarded-Proto` are believed: the failed-key "
        "throttling and the logs then count the client they forward. Unset: no proxy is trusted and every "
        "peer is its own client (a forwarded header cannot change who is throttled).",
    )
    max_active_jobs_per_key: int = Field(
        default=50, ge=1, description="Queued plus running jobs one key may have (429 beyond)."
    )
    max_stored_mb_per_key: int = Field(
        default=20480, ge=1, description="Bytes of clips and artifacts one key may keep, MiB (429 beyond)."
    )
    quota_retry_after_s: int = Field(default=30, ge=1, description="Retry-After of a 429 over a quota.")
    max_frames: int = Field(default=100_000, ge=8, description="Most frames an uploaded clip may hold.")
    max_pixels_per_frame: int = Field(
        default=4096 * 4096, ge=64, description="Largest frame of an uploaded clip, width x height."
    )
    retention_s: float = Field(
        default=7 * 24 * 3600,
        ge=0,
        description="Clips, jobs and artifacts are deleted this long after creation (0: keep forever).",
    )
    cleanup_interval_s: float = Field(default=60, gt=0, description="How often expired data is removed.")
    orphan_grace_s: float = Field(
        default=3600, ge=0, description="Files with no record older than this are removed by the cleanup."
    )
    # Live streams ----------------------------------------------------------------------------
    stream_window: int = Field(
        default=32, ge=2, le=4096, description="Frame messages a stream may have in flight to its worker."
    )
    stream_sessions_per_worker: int = Field(
        default=2, ge=1, le=64, description="Live streams one worker process runs at once."
    )
    stream_start_timeout_s: float = Field(
        default=30, gt=0, description="A stream no worker has taken up within this fails (`no-worker`)."
    )
    stream_worker_timeout_s: float = Field(
        default=10, gt=0, description="A stream whose worker is silent this long fails (`worker-lost`)."
    )
    stream_client_timeout_s: float = Field(
        default=15,
        gt=0,
        description="A connected client silent this long ends its stream (`client-timeout`).",
    )
    stream_resume_window_s: float = Field(
        default=30, ge=0, description="How long a dropped stream waits for its client to resume."
    )
    stream_max_duration_s: float = Field(default=600, gt=0, description="Longest stream capture, seconds.")
    stream_max_frame_mb: int = Field(
        default=32,
        ge=1,
        description="Largest frame message, MiB: a larger one gets the non-fatal `frame-too-large` error "
        "(up to STREAM_MESSAGE_MARGIN_MB beyond; see there).",
    )
    stream_message_margin_mb: int = Field(
        default=16,
        ge=1,
        description="The WebSocket message limit is STREAM_MAX_FRAME_MB plus this, MiB: a frame message "
        "up to this much over the frame limit is answered `frame-too-large` and the stream goes on; a "
        "larger message closes the connection (1009).",
    )
    stream_max_json_depth: int = Field(
        default=16,
        ge=2,
        le=256,
        description="Deepest nesting of arrays and objects in a stream's JSON (a frame header, a text "
        "message); deeper is answered with a non-fatal error before it is parsed.",
    )
    stream_message_queue: int = Field(
        default=4,
        ge=1,
        le=64,
        description="WebSocket messages a connection may have received and not yet relayed (beyond, the "
        "server stops reading from it), bounding what one connection holds in memory.",
    )
    stream_estimate_interval_s: float = Field(
        default=0.2, gt=0, le=0.25, description="Time between `estimate` messages once motion is seen."
    )
    test_hooks: bool = Field(
        default=False,
        description="Fault-injection hooks for the test suite (a clip named `__eigenscope_kill_worker__*` "
        "kills the worker running it; one uploaded as `__eigenscope_slow_probe__*` is validated a minute "
        "late). Never enable in production.",
    )

    @field_validator(
        "redis_url",
        "database_url",
        "api_keys",
        "api_keys_file",
        "published_host",
        "metrics_token",
        "trusted_proxies",
        "callback_hosts",
        "callback_secret",
        "public_url",
        "worker_metrics_port",
        mode="before",
    )
    @classmethod
    def _blank_is_unset(cls, value: Any) -> Any:
        if isinstance(value, str) and not value.strip():
            return None
        return value

    @model_validator(mode="after")
    def _check_limits(self) -> Self:
        if self.task_hard_time_limit_s <= self.task_soft_time_limit_s:
            raise ValueError(
                f"EIGENSCOPE_TASK_HARD_TIME_LIMIT_S={self.task_hard_time_limit_s} must exceed "
                f"EIGENSCOPE_TASK_SOFT_TIME_LIMIT_S={self.task_soft_time_limit_s}"
            )
        if self.visibility_timeout_s is not None and self.visibility_timeout_s <= self.task_hard_time_limit_s:
            raise ValueError(
                f"EIGENSCOPE_VISIBILITY_TIMEOUT_S={self.visibility_timeout_s} must exceed the hard time "
                f"limit {self.task_hard_time_limit_s}, or a long job would be delivered twice"
            )
        if self.callback_hosts and not self.callback_secret:
            raise ValueError(
                "EIGENSCOPE_CALLBACK_HOSTS needs EIGENSCOPE_CALLBACK_SECRET: webhook deliveries are signed "
                "(e.g. `python -c 'import secrets; print(secrets.token_urlsafe(32))'`)"
            )
        return self

    # Derived values ---------------------------------------------------------------------------

    @property
    def embedded(self) -> bool:
        """True when no broker server is configured (filesystem transport in the data directory)."""
        return self.redis_url is None

    @property
    def data_path(self) -> Path:
        """The data directory as an absolute path."""
        return self.data_dir.expanduser().resolve()

    @property
    def effective_database_url(self) -> str:
        """The job store's SQLAlchemy URL."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{self.data_path / 'eigenscope.db'}"

    @property
    def effective_visibility_timeout_s(self) -> float:
        """Redis visibility timeout, always above the hard time limit."""
        if self.visibility_timeout_s is not None:
            return self.visibility_timeout_s
        return self.task_hard_time_limit_s + 600

    @property
    def max_upload_bytes(self) -> int:
        return self.max_upload_mb * 1024 * 1024

    @property
    def max_stored_bytes_per_key(self) -> int:
        return self.max_stored_mb_per_key * 1024 * 1024

    @property
    def ws_max_message_bytes(self) -> int:
        """The WebSocket message limit uvicorn enforces (the frame limit plus its margin)."""
        return (self.stream_max_frame_mb + self.stream_message_margin_mb) * 1024 * 1024

    @property
    def max_json_body_bytes(self) -> int:
        return self.max_json_body_kb * 1024

    @property
    def max_job_body_bytes(self) -> int:
        return self.max_job_body_kb * 1024

    @property
    def broker_dir(self) -> Path:
        """Folders of the embedded filesystem broker."""
        return self.data_path / "broker"

    def child_environment(self) -> dict[str, str]:
        """These settings as ``EIGENSCOPE_*`` variables, for processes started on this machine.

        Plain API keys are never among them: :func:`service.auth.write_digest_file` hands children the
        keys' digests in a file instead (``EIGENSCOPE_API_KEYS_FILE``).
        """
        env: dict[str, str] = {}
        for name, value in self.model_dump().items():
            if value is None or name == "api_keys":
                continue
            if name == "data_dir":
                value = self.data_path
            if name == "api_keys_file":
                value = Path(value).expanduser().resolve()
            env[f"EIGENSCOPE_{name.upper()}"] = str(value)
        return env
