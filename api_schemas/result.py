"""The analysis result: written by the CLI as ``result.json`` and served by the API."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Regime = Literal["ring_down", "steady", "growing", "beating"]


class QualityFlag(BaseModel):
    """A reason why (part of) a result may be unreliable."""

    model_config = ConfigDict(title="QualityFlag", allow_inf_nan=False)

    code: str = Field(description="Stable machine-readable code, e.g. `possibly_aliased`, `no_depth`.")
    message: str = Field(description="What was seen and what to do about it.")
    severity: str = Field(default="warning", description="`info`, `warning` or `error`.")


class RingdownResult(BaseModel):
    """How an object's oscillation decays: amplitude and frequency over sliding windows."""

    model_config = ConfigDict(title="Ringdown", allow_inf_nan=False)

    times_s: list[float] = Field(description="Window centres, seconds from the analysed window's start.")
    amplitude_px: list[float] = Field(description="Displacement amplitude at the object's frequency, pixels.")
    frequency_hz: list[float] = Field(description="Strongest frequency in each window.")
    decay_per_s: float | None = Field(default=None, description="Fitted envelope decay rate σ = ζ ω_n, 1/s.")


class ObjectResult(BaseModel):
    """One vibrating object found in the clip."""

    model_config = ConfigDict(title="ObjectResult", allow_inf_nan=False)

    id: int = Field(ge=1, description="The object's value in `mask.png`.")
    eigenfrequency_hz: float = Field(description="Damped eigenfrequency, Hz.")
    regime: Regime = Field(
        default="ring_down",
        description="How the object moved in the analysed window: `ring_down` (it decays: damping is "
        "measured), `steady` (a sustained or forced vibration that does not decay: damping is null, with "
        "the reason in `null_reasons`), `growing`, or `beating` (two close frequencies not resolved).",
    )
    eigenfrequency_uncertainty_hz: float | None = Field(default=None, description="Standard uncertainty, Hz.")
    natural_frequency_hz: float | None = Field(default=None, description="Undamped natural frequency, Hz.")
    angular_frequency_rad_s: float = Field(description="2π times the undamped natural frequency, rad/s.")
    damping_ratio: float | None = None
    damping_ratio_uncertainty: float | None = None
    amplitude_px: float | None = Field(default=None, description="Amplitude at release, image pixels.")
    amplitude_source: str | None = Field(
        default=None,
        description="`registration` (rigid-body sub-pixel tracking) or `flow` (dense optical flow).",
    )
    amplitude_m: float | None = Field(default=None, description="Amplitude at release, metres.")
    amplitude_uncertainty_m: float | None = None
    depth_m: float | None = Field(default=None, description="Median distance of the object from the camera.")
    motion_direction: list[float] | None = Field(
        default=None, description="Unit vector of the main motion in camera coordinates [x, y, z]."
    )
    stiffness_n_per_m: float | None = None
    stiffness_uncertainty_n_per_m: float | None = None
    mass_kg: float | None = None
    mass_uncertainty_kg: float | None = None
    pixel_count: int = Field(ge=0)
    bbox_px: list[int] = Field(description="[x, y, w, h] of the object's mask, pixels.")
    harmonics_hz: list[float] = Field(default_factory=list)
    release_time_s: float | None = Field(default=None, description="When the object was released.")
    snr_db: float | None = None
    null_reasons: list[str] = Field(
        default_factory=list, description="Why a quantity above is null (e.g. no excitation, no depth)."
    )
    notes: list[str] = Field(
        default_factory=list,
        description="What else was seen: pixels excluded as shadow or background, "
        "motion along the line of sight.",
    )
    ringdown: RingdownResult | None = None


class RejectedPeakResult(BaseModel):
    """A spectral peak that was not reported as an object, and the evidence why."""

    model_config = ConfigDict(title="RejectedPeak")

    frequency_hz: float
    evidence: str = Field(
        description="`camera_motion`, `illumination_flicker`, `codec_keyframes`, `harmonic` (of an object "
        "reported, possibly folded back below the Nyquist rate), `incoherent` (no single coherent "
        "oscillation), `uncertain` (frequency uncertainty a quarter of itself or more) or `out_of_band`."
    )
    reason: str = Field(description="What was seen, in a sentence.")


class Spectrum(BaseModel):
    """Summed motion power spectrum of the clip."""

    model_config = ConfigDict(title="Spectrum", allow_inf_nan=False)

    frequencies_hz: list[float]
    power: list[float]
    noise_power: list[float] | None = Field(
        default=None, description="What static background would sum to at each frequency (the noise floor)."
    )


class Artifacts(BaseModel):
    """Files produced by the analysis: names relative to the output directory, or URLs when served."""

    model_config = ConfigDict(title="Artifacts", allow_inf_nan=False, extra="allow")

    mask: str = Field(
        default="mask.png",
        description="Label image (PNG, 8- or 16-bit, frame size): 0 background, i = object i.",
    )
    overlay: str | None = Field(
        default=None,
        description="Representative frame with each object outlined in its colour and labelled with "
        "id, f, k and m (PNG).",
    )
    frequency_map: str | None = Field(
        default=None,
        description="Per-pixel dominant frequency with a colour bar in Hz; pixels below the noise floor "
        "muted (PNG).",
    )
    spectrum: str | None = Field(
        default=None,
        description="Summed motion spectrum, log scale, with eigenfrequencies, harmonics, noise floor and "
        "rejected artefact peaks marked (PNG).",
    )
    displacement: str | None = Field(
        default=None,
        description="Each object's displacement against time with the fitted damped oscillation and the "
        "release instant (PNG).",
    )
    ringdown: str | None = Field(default=None, description="Spectrogram of each object's ring-down (PNG).")


class AnalysisResult(BaseModel):
    """Everything one analysis measured."""

    model_config = ConfigDict(title="AnalysisResult", allow_inf_nan=False)

    eigenfrequency_hz: float | None = Field(description="The main object's eigenfrequency, Hz.")
    objects: list[ObjectResult]
    spectrum: Spectrum
    artifacts: Artifacts = Field(default_factory=Artifacts)
    quality: list[QualityFlag] = Field(default_factory=list)
    rejected_peaks: list[RejectedPeakResult] = Field(
        default_factory=list, description="Peaks that are not objects, each with the evidence."
    )
    method: str
    parameters: dict[str, object] = Field(description="Every parameter used, defaults included.")
    fps: float = Field(description="The frame rate used, Hz: every frequency scales with it.")
    fps_source: str = Field(
        description="Where the rate came from: `user`, `bundle`, `timestamps`, `container` (a high-speed "
        "camera may have written its playback rate: see the `frame_rate` quality flag) or `metadata` (a "
        "capture rate the file records)."
    )
    frames_used: list[int] = Field(description="[first, last) frame indices of the analysed window.")
    frame_step: int = Field(
        default=1,
        ge=1,
        description="Every frame_step-th frame of frames_used was analysed: spectra, displacement and "
        "ring-down are sampled at fps / frame_step (a long clip of slow motion).",
    )
    frame_size_px: list[int] = Field(description="[width, height] of the input frames.")
    timings_s: dict[str, float] = Field(default_factory=dict)
    version: str
