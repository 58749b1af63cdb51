"""Client of the Eigenscope API (``pip install eigenscope-client``)."""

from eigenscope_client._exceptions import ApiError, EigenscopeError, StreamError, TransportError
from eigenscope_client.streams import AsyncStreamSession, StreamSession, frame_message

__all__ = [
    "ApiError",
    "AsyncStreamSession",
    "EigenscopeError",
    "StreamError",
    "StreamSession",
    "TransportError",
    "frame_message",
]
