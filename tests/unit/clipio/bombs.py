"""Decompression bombs as the hardening review built them, made in about a second each.

- :func:`png_bomb_zip`: a zip of frames whose fourth PNG declares 16000x16000 16-bit RGB; its IDAT is a
  real deflate stream of zeros (1.5 GB decoded, about 1.5 MB stored).
- :func:`npz_bomb`: an ``.npz`` whose ``rgb`` deflates to 96 frames of 4096x4096x3 (4.8 GB of zeros in
  about 4.7 MB).

Deflating gigabytes of zeros takes zlib seconds; both streams are built from one compressed block of
zeros ended by a full flush (which empties the compressor's history), repeated: a valid deflate stream
that inflates to exactly the zeros it stands for.
"""

from __future__ import annotations

import struct
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib import format as npy_format

PNG_BOMB_SIDE = 16000
NPZ_BOMB_SHAPE = (96, 4096, 4096, 3)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _zeros_zlib(total: int, block: int) -> bytes:
    """A zlib stream (header, deflate blocks, Adler-32) of ``total`` zero bytes, ``block`` divides it."""
    assert total % block == 0
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    part = c.compress(bytes(block)) + c.flush(zlib.Z_FULL_FLUSH)
    adler = 1
    zeros = bytes(block)
    for _ in range(total // block):
        adler = zlib.adler32(zeros, adler)
    return b"\x78\xda" + part * (total // block) + b"\x03\x00" + struct.pack(">I", adler)


def png_bomb(side: int = PNG_BOMB_SIDE) -> bytes:
    """A PNG of ``side`` x ``side`` 16-bit RGB pixels, all zero (``side * side * 6`` bytes decoded)."""
    row = 1 + side * 6  # filter byte + samples
    rows_per_block = 100 if side % 100 == 0 else 1
    ihdr = struct.pack(">IIBBBBB", side, side, 16, 2, 0, 0, 0)
    idat = _zeros_zlib(row * side, row * rows_per_block)
    return (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", ihdr)
        + _png_chunk(b"IDAT", idat)
        + _png_chunk(b"IEND", b"")
    )


def png_bomb_zip(path: Path, *, frames: int = 20, bomb_index: int = 3) -> Path:
    """Frames of 64x48 pixels under ``rgb/``; frame ``bomb_index`` is :func:`png_bomb`."""
    import cv2

    rng = np.random.default_rng(0)
    with zipfile.ZipFile(path, "w") as zf:
        for i in range(frames):
            if i == bomb_index:
                data = png_bomb()
            else:
                data = bytes(cv2.imencode(".png", rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))[1])
            zf.writestr(f"rgb/{i:04d}.png", data)
    return path


class _RepeatedZeros:
    """A stand-in for zipfile's deflate compressor that emits a cached block for each block of zeros."""

    def __init__(self) -> None:
        self._c = zlib.compressobj(9, zlib.DEFLATED, -15)
        self._cache: dict[int, bytes] = {}

    def compress(self, data: bytes) -> bytes:
        if len(data) >= 1 << 20 and data.count(0) == len(data):
            if len(data) not in self._cache:
                fresh = zlib.compressobj(9, zlib.DEFLATED, -15)
                self._cache[len(data)] = fresh.compress(data) + fresh.flush(zlib.Z_FULL_FLUSH)
            return self._c.flush(zlib.Z_FULL_FLUSH) + self._cache[len(data)]
        return self._c.compress(data)

    def flush(self, mode: int = zlib.Z_FINISH) -> bytes:
        return self._c.flush(mode)


def npz_bomb(path: Path, shape: tuple[int, ...] = NPZ_BOMB_SHAPE) -> Path:
    """An ``.npz`` of ``rgb`` zeros of ``shape`` (uint8) deflated, with ``fps`` 30."""
    frame = bytes(int(np.prod(shape[1:])))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("rgb.npy", "w", force_zip64=True) as fh:
            fh._compressor = _RepeatedZeros()  # type: ignore[attr-defined]  # test fixture: see the class
            header: dict[str, Any] = {"descr": "|u1", "fortran_order": False, "shape": tuple(shape)}
            npy_format.write_array_header_1_0(fh, header)
            for _ in range(shape[0]):
                fh.write(frame)
        with zf.open("fps.npy", "w") as fh:
            npy_format.write_array(fh, np.asarray(30.0))
    return path
