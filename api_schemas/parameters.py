"""What a job or stream is asked to do: the excitation and the analysis parameters (requests), and the
parameters an analysis used (``AnalysisResult.parameters``)."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator


class StepReleaseExcitation(BaseModel):
    """Object held by a known force, then released: A = F/k."""

    model_config = ConfigDict(title="StepReleaseExcitation", allow_inf_nan=False, extra="forbid")

    type: Literal["step_release"]
    force_n: float = Field(gt=0, description="Holding force, newtons.")
    force_uncertainty_n: float = Field(default=0.0, ge=0)
    object_id: int | None = Field(default=None, ge=1, description="Which object; default the main one.")
    point_px: list[float] | None = Field(
        default=None, min_length=2, max_length=2, description="... or a point [x, y] on the object, pixels."
    )
    box_px: list[float] | None = Field(
        default=None, min_length=4, max_length=4, description="... or a box [x, y, w, h] around it, pixels."
    )


class ImpulseExcitation(BaseModel):
    """Object struck by a known impulse: v0 = J/m."""

    model_config = ConfigDict(title="ImpulseExcitation", allow_inf_nan=False, extra="forbid")

    type: Literal["impulse"]
    impulse_ns: float = Field(gt=0, description="Impulse, newton-seconds.")
    impulse_uncertainty_ns: float = Field(default=0.0, ge=0)
    object_id: int | None = Field(default=None, ge=1, description="Which object; default the main one.")
    point_px: list[float] | None = Field(
        default=None, min_length=2, max_length=2, description="... or a point [x, y] on the object, pixels."
    )
    box_px: list[float] | None = Field(
        default=None, min_length=4, max_length=4, description="... or a box [x, y, w, h] around it, pixels."
    )


Excitation = Annotated[StepReleaseExcitation | ImpulseExcitation, Field(discriminator="type")]

#: One excitation (for the main object, or the one it names), or one per excited object.
ExcitationSpec = Excitation | Annotated[list[Excitation], Field(min_length=1, max_length=16)]


#: Most samples of a force log sent with a request (10 minutes at 1 kHz would be 600,000).
MAX_FORCE_SAMPLES = 200_000
#: Longest text of one number of a force log in JSON, its separator included: a float at full precision
#: (``-1.2345678901234567e-05``) and ``", "``. The job request's body limit leaves room for
#: :data:`MAX_FORCE_SAMPLES` of them in each of four columns (``backend.settings``, ``max_job_body_kb``).
MAX_FORCE_NUMBER_BYTES = 26


class ForceLog(BaseModel):
    """A force sensor's log sent with the clip: its push, hold and release, or its strike, is the
    excitation (a typed one overrides it). Either the three components ``fx``, ``fy``, ``fz`` (the force's
    magnitude along its dominant direction is used) or one signed magnitude ``force_n``."""

    model_config = ConfigDict(title="ForceLog", allow_inf_nan=False, extra="forbid")

    time_s: list[float] = Field(
        min_length=8,
        max_length=MAX_FORCE_SAMPLES,
        description="Sample times, seconds, strictly increasing; 0 is the clip's first frame (see "
        "`offset_s`).",
    )
    fx: list[float] | None = Field(default=None, description="Force components, newtons.")
    fy: list[float] | None = None
    fz: list[float] | None = None
    force_n: list[float] | None = Field(default=None, description="... or one signed magnitude, newtons.")
    offset_s: float = Field(
        default=0.0, description="Added to every time: minus the log's time at the clip's first frame."
    )
    frame_id: str | None = Field(default=None, max_length=256, description="The sensor's frame, if known.")
    name: str = Field(default="force log", max_length=256, description="Where the log came from (a file).")

    @field_validator("time_s")
    @classmethod
    def _increasing(cls, times: list[float]) -> list[float]:
        """Times strictly increasing: the first that repeats or runs backwards is named, with the fix."""
        for i in range(1, len(times)):
            if not times[i] > times[i - 1]:
                how = "repeats" if times[i] == times[i - 1] else "runs backwards from"
                raise ValueError(
                    f"times must increase strictly, but time_s[{i}] = {times[i]:.9g} s {how} "
                    f"time_s[{i - 1}] = {times[i - 1]:.9g} s; sort the samples by time and drop repeated "
                    "ones, or fix the sensor's clock"
                )
        return times

    @field_validator("fx", "fy", "fz", "force_n")
    @classmethod
    def _one_value_per_time(cls, column: list[float] | None, info: ValidationInfo) -> list[float] | None:
        """Each column as long as ``time_s`` (checked once ``time_s`` is valid)."""
        times = info.data.get("time_s")
        if column is not None and times is not None and len(column) != len(times):
            raise ValueError(
                f"{info.field_name} has {len(column)} values but time_s has {len(times)}; give one value "
                "per time"
            )
        return column

    @model_validator(mode="after")
    def _one_form(self) -> ForceLog:
        """Three components or one magnitude, and times that stay finite once ``offset_s`` is added."""
        given = [c for c in (self.fx, self.fy, self.fz) if c is not None]
        if self.force_n is not None and given:
            raise ValueError("give either fx, fy and fz or force_n, not both")
        if self.force_n is None and len(given) != 3:
            raise ValueError("give all three of fx, fy and fz, or force_n alone")
        if not all(math.isfinite(t + self.offset_s) for t in (self.time_s[0], self.time_s[-1])):
            raise ValueError(f"time_s plus offset_s={self.offset_s:g} overflows; give times in seconds")
        return self

    def summary(self) -> ForceLogSummary:
        """What a job shows of its log: name, size and span on the clip's clock, not the samples."""
        return ForceLogSummary(
            name=self.name,
            samples=len(self.time_s),
            start_s=self.time_s[0] + self.offset_s,
            end_s=self.time_s[-1] + self.offset_s,
            columns=["force_n"] if self.force_n is not None else ["fx", "fy", "fz"],
            frame_id=self.frame_id,
        )


class ForceLogSummary(BaseModel):
    """The force log a job was sent with, as the job shows it (its samples are not echoed)."""

    model_config = ConfigDict(
        title="ForceLogSummary", allow_inf_nan=False, json_schema_serialization_defaults_required=True
    )

    name: str = Field(description="The log's `name` (a file).")
    samples: int = Field(ge=0, description="Samples in the log.")
    start_s: float = Field(description="First sample's time on the clip's clock (`offset_s` added), s.")
    end_s: float = Field(description="Last sample's time on the clip's clock (`offset_s` added), s.")
    columns: list[str] = Field(description="The force's columns: `fx`, `fy`, `fz`, or `force_n`.")
    frame_id: str | None = Field(default=None, description="The sensor's frame, if given.")


#: Fewest frames of an analysis window (the pipeline's ``workers.pipeline.clipio.types.MIN_FRAMES``, which
#: a test holds equal: 16 frames give 15 flow maps and 7 frequencies above zero).
MIN_WINDOW_FRAMES = 16


class AnalysisParameters(BaseModel):
    """Analysis options; every field has a default that works without tuning."""

    model_config = ConfigDict(title="AnalysisParameters", allow_inf_nan=False, extra="forbid")

    method: Literal["default", "paper"] = "default"
    flow: Literal["farneback", "dis"] | None = Field(
        default=None, description="Optical flow; default depends on the method."
    )
    frames: int | None = Field(
        default=None,
        ge=MIN_WINDOW_FRAMES,
        le=100_000,
        description=f"Analysis window length N, frames (at least {MIN_WINDOW_FRAMES}).",
    )
    start_frame: int | None = Field(default=None, ge=0)
    fps: float | None = Field(default=None, gt=0, le=100_000, description="True recording rate, Hz.")
    fx: float | None = Field(default=None, gt=0)
    fy: float | None = Field(default=None, gt=0)
    cx: float | None = None
    cy: float | None = None
    depth_scale: float | None = Field(default=None, gt=0, description="Metres per depth unit.")
    depth_m: float | None = Field(
        default=None, gt=0, description="Object distance when the clip has no depth."
    )
    color_topic: str | None = Field(
        default=None,
        max_length=256,
        description="Bag topic of the colour images (default: chosen automatically).",
    )
    depth_topic: str | None = Field(
        default=None,
        max_length=256,
        description="Bag topic of the depth images (default: chosen automatically; `none` ignores depth).",
    )
    force_topic: str | None = Field(
        default=None,
        max_length=256,
        description="Bag topic of the wrist force/torque sensor (geometry_msgs/WrenchStamped or Wrench) "
        "whose push, hold and release or strike is the excitation (default: the bag's one force topic, "
        "if any; a typed excitation overrides it).",
    )
    min_frequency_hz: float | None = Field(default=None, ge=0)
    max_frequency_hz: float | None = Field(default=None, gt=0)

    @field_validator("max_frequency_hz")
    @classmethod
    def _band_not_empty(cls, value: float | None, info: ValidationInfo) -> float | None:
        """The band's one check for every request (jobs, streams, the CLI): its top above its bottom.
        (Whether it fits below the clip's Nyquist rate is known once the clip is.)"""
        low = info.data.get("min_frequency_hz")
        if value is not None and low is not None and value <= low:
            raise ValueError(f"max_frequency_hz={value:g} must exceed min_frequency_hz={low:g}")
        return value


class SegmentationParameters(BaseModel):
    """How the moving pixels were grouped into objects."""

    model_config = ConfigDict(title="SegmentationParameters", allow_inf_nan=False)

    noise_factor: float | None = None
    relative_level: float | None = None
    purity: float | None = None
    band_bins: float | None = None
    min_area_fraction: float | None = None


class ParametersUsed(BaseModel):
    """Every parameter an analysis used, defaults included (``AnalysisResult.parameters``): the request's own
    (``overrides``), the excitations, and what the server resolved (flow, window, band, segmentation)."""

    model_config = ConfigDict(
        title="ParametersUsed",
        allow_inf_nan=False,
        extra="allow",
        json_schema_serialization_defaults_required=True,
    )

    method: Literal["default", "paper"] = "default"
    flow: Literal["farneback", "dis"] | None = Field(default=None, description="The optical flow used.")
    flow_scale: float | str | None = Field(
        default=None, description="Scale of the frames the flow ran on, or `auto` (chosen per clip)."
    )
    dis_preset: Literal["ultrafast", "fast", "fine", "medium"] | None = Field(
        default=None, description="DIS preset, when the flow is DIS."
    )
    flow_threads: int | None = Field(default=None, description="Frame pairs whose flow ran at once.")
    frames: int | None = Field(default=None, description="Window length asked for (None: automatic).")
    start_frame: int | None = Field(default=None, description="First frame of the window.")
    min_frequency_hz: float | None = None
    max_frequency_hz: float | None = None
    depth_m: float | None = None
    segmentation: SegmentationParameters | None = None
    max_objects: int | None = None
    auto_window: bool | None = Field(default=None, description="Whether a long clip was surveyed first.")
    max_window_mib: float | None = Field(default=None, description="Memory budget of an automatic window.")
    fps: float | None = Field(default=None, description="The frame rate used, Hz.")
    fps_source: str | None = Field(default=None, description="Where the rate came from (see `fps_source`).")
    excitation: list[Excitation] | None = Field(default=None, description="The excitations given.")
    overrides: AnalysisParameters = Field(
        default_factory=lambda: AnalysisParameters(), description="The request's own parameters."
    )
    live: bool | None = Field(default=None, description="`true`: the analysis of a live stream.")
    target_relative_uncertainty: float | None = Field(
        default=None, description="A live stream's convergence target."
    )
