"""Pydantic models shared by the API (``service``) and the workers (``workers``).

This package is the only code both sides import. It holds the wire format: requests, the job
record, the analysis result and RFC 9457 problem details.
"""

from api_schemas.clip import CameraIntrinsicsModel, ClipInfoModel, ClipList
from api_schemas.job import (
    AnalysisParameters,
    CallbackState,
    Excitation,
    ExcitationSpec,
    ImpulseExcitation,
    JobCreate,
    JobList,
    JobModel,
    JobStatus,
    StepReleaseExcitation,
)
from api_schemas.problem import Problem
from api_schemas.result import (
    AnalysisResult,
    Artifacts,
    ObjectResult,
    QualityFlag,
    RejectedPeakResult,
    RingdownResult,
    Spectrum,
)
from api_schemas.stream import (
    FrameHeader,
    LiveEstimateModel,
    ServerMessage,
    StreamCreate,
    StreamList,
    StreamModel,
)

__all__ = [
    "AnalysisParameters",
    "AnalysisResult",
    "Artifacts",
    "CallbackState",
    "CameraIntrinsicsModel",
    "ClipInfoModel",
    "ClipList",
    "Excitation",
    "ExcitationSpec",
    "FrameHeader",
    "ImpulseExcitation",
    "JobCreate",
    "JobList",
    "JobModel",
    "JobStatus",
    "LiveEstimateModel",
    "ObjectResult",
    "Problem",
    "QualityFlag",
    "RejectedPeakResult",
    "RingdownResult",
    "ServerMessage",
    "Spectrum",
    "StepReleaseExcitation",
    "StreamCreate",
    "StreamList",
    "StreamModel",
]
