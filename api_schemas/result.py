"""The analysis result: written by the CLI as ``result.json`` and served by the API."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from api_schemas.parameters import ParametersUsed

Regime = Literal["ring_down", "steady", "growing", "beating"]
#: Every quality flag the analysis reports (``tests/unit/service/test_enumerations.py`` keeps this equal to
#: the codes ``workers.pipeline`` writes).
QualityCode = Literal[
    "artefact_peak",
    "band_edge",
    "blank_frames",
    "close_frequencies",
    "damaged_file",
    "few_periods",
    "force_recording",
    "frame_rate",
    "longer_window",
    "low_snr",
    "no_depth",
    "no_motion",
    "paper_method",
    "possibly_aliased",
    "saturation",
    "survey_disagrees",
    "uneven_timing",
    "window",
]
Severity = Literal["info", "warning", "error"]
#: Why a spectral peak is not reported as an object.
Evidence = Literal[
    "camera_motion",
    "illumination_flicker",
    "codec_keyframes",
    "harmonic",
    "same_pixels",
    "incoherent",
    "not_significant",
    "uncertain",
    "out_of_band",
]
#: Where a frame rate came from.
FpsSource = Literal["user", "bundle", "container", "timestamps", "metadata", "unknown"]
#: How the amplitude was measured.
AmplitudeSource = Literal["registration", "flow"]

#: The configuration of a model the API only sends: every member is sent, defaults included, so the
#: document marks them required (a generated client then has no "unset" state for them).
RESPONSE = ConfigDict(allow_inf_nan=False, json_schema_serialization_defaults_required=True)


class QualityFlag(BaseModel):
    """A reason why (part of) a result may be unreliable."""

    model_config = ConfigDict(title="QualityFlag", **RESPONSE)

    code: QualityCode = Field(
        description="Stable machine-readable code, e.g. `possibly_aliased`, `no_depth`."
    )
    message: str = Field(description="What was seen and what to do about it.")
    severity: Severity = Field(default="warning", description="`info`, `warning` or `error`.")


class RingdownResult(BaseModel):
    """How an object's oscillation decays: amplitude and frequency over sliding windows."""

    model_config = ConfigDict(title="Ringdown", **RESPONSE)

    times_s: list[float] = Field(description="Window centres, seconds from the analysed window's start.")
    amplitude_px: list[float] = Field(description="Displacement amplitude at the object's frequency, pixels.")
    frequency_hz: list[float] = Field(description="Strongest frequency in each window.")
    decay_per_s: float | None = Field(default=None, description="Fitted envelope decay rate σ = ζ ω_n, 1/s.")


class ExcitationUsed(BaseModel):
    """The excitation an object's stiffness and mass were measured with, and where it came from."""

    model_config = ConfigDict(title="ExcitationUsed", **RESPONSE)

    type: Literal["step_release", "impulse", "forced"] = Field(
        description="`forced`: a recorded force that kept acting; stiffness and mass then come from the "
        "response between the force and the motion (one degree of freedom; its damping in `notes`)."
    )
    value: float = Field(
        description="Held force, newtons (step_release), impulse, newton-seconds (impulse), or the force's "
        "RMS, newtons (forced)."
    )
    uncertainty: float = Field(ge=0, description="Its standard uncertainty, same unit.")
    release_time_s: float | None = Field(
        default=None,
        description="When the force sensor saw it let go (step_release) or struck (impulse), seconds from "
        "the clip's first frame: the fit's release instant. Null for a typed excitation.",
    )
    source: str = Field(
        description="`request` (typed), or the recording: `topic <name>` of a bag, `log <name>` of a force "
        "log."
    )
    notes: list[str] = Field(
        default_factory=list,
        description="E.g. the direction the force was taken along, or a typed value overriding a recorded "
        "one.",
    )


class ModeResult(BaseModel):
    """One mode of an object: a narrow-band component of its pixels' motion, with a shape of its own."""

    model_config = ConfigDict(title="Mode", **RESPONSE)

    frequency_hz: float = Field(description="Damped frequency of the mode, Hz.")
    frequency_uncertainty_hz: float | None = Field(default=None, description="Standard uncertainty, Hz.")
    damping_ratio: float | None = Field(default=None, description="Null when the mode does not decay.")
    damping_ratio_uncertainty: float | None = None
    energy_share: float = Field(ge=0, le=1, description="Share of the object's motion energy in this mode.")
    regime: Regime = Field(description="`ring_down`, `steady` or `growing`, as for the object.")
    complexity: float = Field(
        ge=0,
        le=1,
        description="How far the mode's shape is from a real (standing) one: 0 for a real mode, up to 1 "
        "for a travelling wave.",
    )


class ModeHarmonicResult(BaseModel):
    """A line of an object's motion at an integer multiple of one of its modes, with that mode's shape: the
    motion is periodic but not sinusoidal (the evidence is the MAC between the two shapes)."""

    model_config = ConfigDict(title="ModeHarmonic", **RESPONSE)

    frequency_hz: float
    fundamental_hz: float = Field(description="The mode's frequency, Hz.")
    order: int = Field(ge=2)
    mac: float = Field(ge=0, le=1, description="MAC between the line's shape and the mode's.")


class ObjectResult(BaseModel):
    """One vibrating object found in the clip."""

    model_config = ConfigDict(title="ObjectResult", **RESPONSE)

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
    amplitude_source: AmplitudeSource | None = Field(
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
    excitation: ExcitationUsed | None = Field(
        default=None, description="The excitation its stiffness and mass were measured with (null: none)."
    )
    snr_db: float | None = None
    false_alarm_probability: float | None = Field(
        default=None,
        ge=0,
        le=1,
        description="Probability, per clip, that noise alone (sensor, codec) gives a peak as high as this "
        "object's anywhere in the analysed band: the detection statistic's (see `detection`). Objects are "
        "reported when it is at most `detection.max_false_alarm`.",
    )
    null_reasons: list[str] = Field(
        default_factory=list, description="Why a quantity above is null (e.g. no excitation, no depth)."
    )
    notes: list[str] = Field(
        default_factory=list,
        description="What else was seen: pixels excluded as shadow or background, "
        "motion along the line of sight.",
    )
    ringdown: RingdownResult | None = None
    modes: list[ModeResult] = Field(
        default_factory=list,
        description="The narrow-band components of the object's motion, strongest first, each with its "
        "frequency, damping and share of the motion (their shapes are in the `modes` artifact, drawn in "
        "`mode_shapes` and `mode_animation`). A line at an integer multiple of a mode with the same shape "
        "is one of `mode_harmonics` instead.",
    )
    mode_harmonics: list[ModeHarmonicResult] = Field(
        default_factory=list,
        description="Lines at integer multiples of a mode that move with its shape (MAC at least 0.8): "
        "harmonics of a non-sinusoidal motion, not modes.",
    )
    mode_mac: list[list[float]] | None = Field(
        default=None,
        description="MAC (modal assurance criterion) between the modes' shapes, in the order of `modes`: 1 "
        "for the same shape, 0 for orthogonal ones.",
    )


class RejectedPeakResult(BaseModel):
    """A spectral peak that was not reported as an object, and the evidence why."""

    model_config = ConfigDict(title="RejectedPeak", **RESPONSE)

    frequency_hz: float
    evidence: Evidence = Field(
        description="`camera_motion`, `illumination_flicker`, `codec_keyframes`, `harmonic` (of an object "
        "reported, possibly folded back below the Nyquist rate), `same_pixels` (another motion of a "
        "reported object's pixels, not its harmonic: a higher mode), `incoherent`, `not_significant` "
        "(noise alone gives a peak as high too often), `uncertain` (frequency uncertainty a quarter of "
        "itself or more) or `out_of_band`."
    )
    reason: str = Field(description="What was seen, in a sentence.")
    figures: dict[str, float] = Field(
        default_factory=dict,
        description="The numbers behind the verdict, named with their units: for `codec_keyframes` the "
        "period of the keyframes in frames, the comb's spacing, the order, the peak's distance from its "
        "tooth and the tolerance (its frequency uncertainty); for every artefact `localised_share`; for "
        "`not_significant` the false-alarm probability and the bound.",
    )


class Detection(BaseModel):
    """How objects were told from noise: the scan statistic's law on this clip."""

    model_config = ConfigDict(title="Detection", **RESPONSE)

    statistic: str = Field(
        default="scan",
        description="`scan`: the largest confidence-weighted, coherently pooled motion power over every "
        "region of the picture at each frequency, its law (Gumbel, of its logarithm) fitted on the clip's "
        "own frequencies away from any peak.",
    )
    max_false_alarm: float = Field(description="Objects are reported at or below this per-clip probability.")
    location: float = Field(description="Location of the fitted law of log T.")
    scale: float = Field(description="Scale of the fitted law of log T.")
    bins_searched: int = Field(description="Frequencies searched (the per-clip probability allows for each).")
    bins_fitted: int = Field(description="Frequencies the law was fitted on.")


class Spectrum(BaseModel):
    """Summed motion power spectrum of the clip."""

    model_config = ConfigDict(title="Spectrum", **RESPONSE)

    frequencies_hz: list[float]
    power: list[float]
    noise_power: list[float] | None = Field(
        default=None, description="What static background would sum to at each frequency (the noise floor)."
    )


#: The files a job serves (``GET /v1/jobs/{job_id}/artifacts/{name}``): its images and ``result.json``.
ArtifactName = Literal[
    "mask.png",
    "overlay.png",
    "frequency_map.png",
    "spectrum.png",
    "displacement.png",
    "ringdown.png",
    "modes.npz",
    "modes.png",
    "modes.gif",
    "result.json",
]
ARTIFACT_NAMES: tuple[str, ...] = ArtifactName.__args__  # type: ignore[attr-defined]


class Artifacts(BaseModel):
    """Files produced by the analysis: names relative to the output directory, or URLs when served (the
    last segment of each URL is one of the artifact names the API serves, `ArtifactName`)."""

    model_config = ConfigDict(title="Artifacts", **RESPONSE)

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
    modes: str | None = Field(
        default=None,
        description="Each object's mode shapes and frequencies (NumPy .npz): `object_<id>_shapes`, float32 "
        "(modes, H, W, 2), displacement in input pixels, NaN outside the object; "
        "`object_<id>_frequencies_hz`, `object_<id>_damping_ratio`, `object_<id>_energy_share` and "
        "`object_<id>_mac`, in the order of the object's `modes`; where depth (or a given distance) and "
        "intrinsics allow, `object_<id>_shapes_m`, float32 (modes, H, W, 3): the displacement in metres, x "
        "and y across the line of sight, z along it (from the depth series; NaN without one); when a mode is "
        "complex (a travelling wave, heavy damping), `object_<id>_shapes_imag`: the imaginary parts, so that "
        "the complex shape is `shapes + 1j * shapes_imag`.",
    )
    mode_shapes: str | None = Field(
        default=None,
        description="Each object's mode shapes over its crop of the frame (PNG): one row per object, one "
        "panel per mode, the frame dimmed with the shape drawn as arrows and a deformed outline in the "
        "object's colour, magnified (the factor is in the label), labelled with the object's id, the "
        "mode's number, its frequency and its damping ratio (or steady); a note when no object has modes.",
    )
    mode_animation: str | None = Field(
        default=None,
        description="The same panels animated (looping GIF): each object's pixels moving in the mode's "
        "magnified shape, one cycle of every mode in step.",
    )
    result: str = Field(
        default="result.json", description="This result as a file (JSON, an `AnalysisResult`)."
    )


class AnalysisResult(BaseModel):
    """Everything one analysis measured."""

    model_config = ConfigDict(title="AnalysisResult", **RESPONSE)

    eigenfrequency_hz: float | None = Field(description="The main object's eigenfrequency, Hz.")
    objects: list[ObjectResult]
    spectrum: Spectrum
    artifacts: Artifacts = Field(default_factory=Artifacts)
    quality: list[QualityFlag] = Field(default_factory=list)
    rejected_peaks: list[RejectedPeakResult] = Field(
        default_factory=list, description="Peaks that are not objects, each with the evidence."
    )
    detection: Detection | None = Field(default=None, description="How objects were told from noise.")
    method: Literal["default", "paper"] = Field(description="The analysis method.")
    parameters: ParametersUsed = Field(description="Every parameter used, defaults included.")
    fps: float = Field(description="The frame rate used, Hz: every frequency scales with it.")
    fps_source: FpsSource = Field(
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
