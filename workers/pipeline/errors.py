"""Domain errors raised by the measuring library.

Every error carries a message that names the problem and says how to fix it. Callers map the classes to
exit codes (CLI) and HTTP statuses (API) without parsing messages.
"""

from __future__ import annotations


class EigenscopeError(Exception):
    """Base class of every error the measuring library raises on bad input or impossible analyses."""

    #: Stable machine-readable code, used as the problem type suffix by the API.
    code = "eigenscope-error"


class ClipError(EigenscopeError):
    """The clip is malformed: missing data, wrong dtype or shape, inconsistent streams, bad metadata."""

    code = "invalid-clip"


class UnsupportedFormatError(ClipError):
    """The file is not a clip format Eigenscope can read."""

    code = "unsupported-format"


class ClipTooLargeError(ClipError):
    """The clip exceeds a configured cap (bytes, entries, frames or pixels)."""

    code = "clip-too-large"


class ParameterError(EigenscopeError):
    """An analysis parameter is out of range or inconsistent with the clip."""

    code = "invalid-parameter"


class AnalysisError(EigenscopeError):
    """The clip is valid but the analysis cannot produce a result (for example: nothing moves)."""

    code = "analysis-failed"


class ForceError(ParameterError):
    """The force recording cannot give the excitation: a malformed force log or series (times running
    backwards, non-finite values, missing columns, too few samples), or a force with no hold, release or
    strike above its noise. The message says what is wrong and how to fix it."""

    code = "invalid-force"
