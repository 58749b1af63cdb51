"""Pydantic models shared by the API (``service``) and the workers (``workers``).

This package is the only code both sides import. It holds the wire format: requests, the job
record, the analysis result and RFC 9457 problem details.
"""

from api_schemas.clip import CameraIntrinsicsModel, ClipInfoModel, ClipList
from api_schemas.job import (
    CallbackState,
    JobCreate,
    JobEvent,
    JobList,
    JobModel,
    JobStage,
    JobStatus,
    JobSummary,
    ResultSummary,
)
from api_schemas.parameters import (
    AnalysisParameters,
    Excitation,
    ExcitationSpec,
    ForceLog,
    ForceLogSummary,
    ImpulseExcitation,
    ParametersUsed,
    StepReleaseExcitation,
)
from api_schemas.problem import FieldError, Problem
from api_schemas.result import (
    ARTIFACT_NAMES,
    AnalysisResult,
    ArtifactName,
    Artifacts,
    Detection,
    ExcitationUsed,
    ModeHarmonicResult,
    ModeResult,
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
    "ARTIFACT_NAMES",
    "AnalysisParameters",
    "AnalysisResult",
    "ArtifactName",
    "Artifacts",
    "CallbackState",
    "CameraIntrinsicsModel",
    "ClipInfoModel",
    "ClipList",
    "Detection",
    "Excitation",
    "ExcitationSpec",
    "ExcitationUsed",
    "FieldError",
    "ForceLog",
    "ForceLogSummary",
    "FrameHeader",
    "ImpulseExcitation",
    "JobCreate",
    "JobEvent",
    "JobList",
    "JobModel",
    "JobStage",
    "JobStatus",
    "JobSummary",
    "LiveEstimateModel",
    "ModeHarmonicResult",
    "ModeResult",
    "ObjectResult",
    "ParametersUsed",
    "Problem",
    "QualityFlag",
    "RejectedPeakResult",
    "ResultSummary",
    "RingdownResult",
    "ServerMessage",
    "Spectrum",
    "StepReleaseExcitation",
    "StreamCreate",
    "StreamList",
    "StreamModel",
]
