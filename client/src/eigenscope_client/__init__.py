"""Python client of the Eigenscope HTTP API, for robot code and lab scripts.

    from eigenscope_client import Client, ForceLog, StepRelease

    with Client("http://127.0.0.1:8000") as es:
        job = es.analyze("clip.npz", excitation=StepRelease(force_n=10)).raise_for_status()
        print(job.result.eigenfrequency_hz, job.result.main.mass_kg)
        es.download_artifact(job, "mask", "mask.png")
        # Or the robot's force sensor as the excitation: its log (CSV or JSON) sent with the clip.
        log = ForceLog.from_file("push.csv")
        camera = {"depth_m": 0.9, "fx": 615.0, "fy": 615.0}  # a video without depth or intrinsics
        job = es.analyze("push.mp4", force_log=log, parameters=camera).raise_for_status()

:class:`Client` blocks; :class:`AsyncClient` has the same methods for ``async`` code. Live streams of
frames from a robot's camera: :class:`StreamSession` (``pip install 'eigenscope-client[streams]'``).
Every error is an :class:`EigenscopeError`; problem documents from the server become :class:`APIError`
subclasses.
"""

from eigenscope_client._client import OPERATIONS, AsyncClient, Client
from eigenscope_client._errors import (
    APIError,
    AuthenticationError,
    BadRequestError,
    ConflictError,
    EigenscopeError,
    ForceLogError,
    InsufficientStorageError,
    InvalidRequestError,
    JobFailedError,
    NotFoundError,
    PayloadTooLargeError,
    PermissionDeniedError,
    RateLimitError,
    ServerError,
    ServiceUnavailableError,
    StreamError,
    TransportError,
    UnsupportedMediaTypeError,
    WaitTimeoutError,
)
from eigenscope_client._force_log import ForceLog
from eigenscope_client._models import (
    FINAL_STATUSES,
    AnalysisParameters,
    AnalysisResult,
    Callback,
    CameraIntrinsics,
    Clip,
    Detection,
    Excitation,
    ExcitationUsed,
    ForceLogSummary,
    Impulse,
    Job,
    JobStatus,
    JobSummary,
    Mode,
    ModeHarmonic,
    ObjectResult,
    Page,
    Problem,
    QualityFlag,
    RejectedPeak,
    ResultSummary,
    Ringdown,
    Spectrum,
    StepRelease,
    Stream,
)
from eigenscope_client._upload import ProgressCallback
from eigenscope_client._version import __version__
from eigenscope_client.streams import AsyncStreamSession, StreamSession, frame_message

__all__ = [
    "FINAL_STATUSES",
    "OPERATIONS",
    "APIError",
    "AnalysisParameters",
    "AnalysisResult",
    "AsyncClient",
    "AsyncStreamSession",
    "AuthenticationError",
    "BadRequestError",
    "Callback",
    "CameraIntrinsics",
    "Client",
    "Clip",
    "ConflictError",
    "Detection",
    "EigenscopeError",
    "Excitation",
    "ExcitationUsed",
    "ForceLog",
    "ForceLogError",
    "ForceLogSummary",
    "Impulse",
    "InsufficientStorageError",
    "InvalidRequestError",
    "Job",
    "JobFailedError",
    "JobStatus",
    "JobSummary",
    "Mode",
    "ModeHarmonic",
    "NotFoundError",
    "ObjectResult",
    "Page",
    "PayloadTooLargeError",
    "PermissionDeniedError",
    "Problem",
    "ProgressCallback",
    "QualityFlag",
    "RateLimitError",
    "RejectedPeak",
    "ResultSummary",
    "Ringdown",
    "ServerError",
    "ServiceUnavailableError",
    "Spectrum",
    "StepRelease",
    "Stream",
    "StreamError",
    "StreamSession",
    "TransportError",
    "UnsupportedMediaTypeError",
    "WaitTimeoutError",
    "__version__",
    "frame_message",
]
