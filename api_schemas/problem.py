"""RFC 9457 problem details."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class FieldError(BaseModel):
    """One field of a request that was refused, and why."""

    model_config = ConfigDict(extra="allow", title="FieldError")

    loc: list[str | int] = Field(
        description="Where the field is: `body`, `query`, `path` or `header`, then its name and the names "
        '(or list indices) down to it, e.g. `["body", "excitation", "force_n"]`.'
    )
    msg: str = Field(description="What is wrong with it, and what to send instead.")
    type: str | None = Field(
        default=None, description="Machine-readable kind, e.g. `missing`, `value_error`."
    )


class Problem(BaseModel):
    """An RFC 9457 ``application/problem+json`` document.

    Extra members are allowed (RFC 9457 section 3.2); ``errors`` carries field-level
    validation failures.
    """

    model_config = ConfigDict(extra="allow", title="Problem", allow_inf_nan=False)

    type: str = Field(default="about:blank", description="URI identifying the problem type.")
    title: str = Field(description="Short, human-readable summary of the problem type.")
    status: int = Field(ge=100, le=599, description="HTTP status code.")
    detail: str | None = Field(default=None, description="Explanation specific to this occurrence.")
    instance: str | None = Field(
        default=None, description="URI of this occurrence (usually the request path)."
    )
    errors: list[FieldError] | None = Field(
        default=None, description="Field-level errors, each with `loc` and `msg`."
    )
