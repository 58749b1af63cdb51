"""Format detection from file content (magic bytes, archive layout, container probe), not the extension.

==============  ==================================================================================
format          recognised by
==============  ==================================================================================
``npz``         zip whose top level holds ``rgb.npy``
``zip-frames``  zip (or folder) with ``rgb/*.png|jpg`` (optionally ``depth/*.png``, ``camera.json``)
``tum``         zip (or folder) with ``rgb.txt`` (TUM RGB-D layout), possibly in one top folder
``open3d``      zip (or folder) with ``color/*.jpg|png`` (Open3D RGB-D layout: ``depth/``,
                ``camera_intrinsic.json``, ``config.json``)
``k4a-mkv``     Matroska with a K4A depth track (Azure Kinect / Orbbec Femto recording)
``video``       any file FFmpeg demuxes with a video stream; or a zip holding one video file
``ros1-bag``    ``#ROSBAG V2.0`` magic
``ros2-bag``    MCAP magic, SQLite magic (``.db3``), a bag folder or a zip with ``metadata.yaml`` /
                ``*.mcap`` / ``*.db3``
==============  ==================================================================================
"""

from __future__ import annotations

import zipfile
from pathlib import Path

from workers.pipeline.clipio._archive import ZIP_ERRORS, Archive, common_root, visible
from workers.pipeline.clipio.open3d import is_open3d_layout
from workers.pipeline.clipio.types import ClipOverrides, ClipReader, ReadLimits
from workers.pipeline.errors import ClipError, ParameterError, UnsupportedFormatError

FORMATS = ("npz", "zip-frames", "tum", "open3d", "k4a-mkv", "video", "ros1-bag", "ros2-bag")
_SUPPORTED = (
    "supported: .npz bundle, zip of rgb/ (+depth/) frames, TUM RGB-D zip, Open3D RGB-D zip (color/, depth/), "
    "Azure Kinect / Orbbec .mkv, video (mp4/avi/mkv/mov), ROS 1 .bag, ROS 2 .mcap/.db3 or zipped bag folder"
)
_VIDEO_EXTS = (".mp4", ".m4v", ".avi", ".mkv", ".mov", ".webm", ".mpg", ".mpeg", ".wmv", ".flv", ".ts")
_IMAGE_EXTS = (".png", ".jpg", ".jpeg")
_EBML_MAGIC = b"\x1a\x45\xdf\xa3"


def _zip_layout(names: list[str]) -> str | None:
    names = visible(names)
    # An archive of top-level .npy arrays is an npz bundle even without 'rgb': its reader then names the
    # missing key and how to save it.
    if any(n.removesuffix(".npy") == "rgb" for n in names) or (
        names and all(n.endswith(".npy") and "/" not in n for n in names)
    ):
        return "npz"
    root = common_root(names)
    rel = [n[len(root) :] for n in names if n.startswith(root)]
    if "metadata.yaml" in rel or any(n.endswith((".mcap", ".db3")) for n in rel):
        return "ros2-bag"
    if "rgb.txt" in rel:
        return "tum"
    if any(n.startswith("rgb/") and n.lower().endswith(_IMAGE_EXTS) for n in rel):
        return "zip-frames"
    if is_open3d_layout(rel):
        return "open3d"
    if any(n.lower().endswith(_VIDEO_EXTS) for n in rel):
        return "video"
    return None


def _is_zip(path: Path) -> bool:
    if not path.is_file():
        return False
    with path.open("rb") as fh:
        return fh.read(2) == b"PK"


def _probe_video(path: Path) -> str | None:
    """None when FFmpeg finds a video stream in an allowed container, else why not.

    The file is opened as :func:`~workers.pipeline.clipio.video.open_video` opens it: a playlist, or a
    container that is not on the allow-list, is refused here (a :class:`ClipError`) before it reads
    anything but itself.
    """
    import av

    from workers.pipeline.clipio.video import open_video

    try:
        opened = open_video(path, path.name)
    except (av.error.FFmpegError, OSError, ValueError, EOFError) as exc:
        return (str(exc).strip() or type(exc).__name__).splitlines()[0][:160]
    try:
        return None if opened.container.streams.video else "no video stream"
    finally:
        opened.close()


def _container_kind(head: bytes) -> str | None:
    if head[4:8] == b"ftyp":
        return "MP4/MOV"
    if head.startswith(b"RIFF") and head[8:12] == b"AVI ":
        return "AVI"
    if head.startswith(_EBML_MAGIC):
        return "Matroska/WebM"
    return None


def detect_format(path: str | Path) -> str:
    """Name the clip format of the file (or folder) at ``path`` from its content.

    Parameters
    ----------
    path : path-like
        A clip file, or a folder holding a ROS 2 bag, a TUM sequence, an Open3D dataset or ``rgb/`` frames.

    Returns
    -------
    str
        One of :data:`FORMATS`.

    Raises
    ------
    ClipError
        When the file is empty, unreadable, or looks like a format (by magic or extension) but is broken.
    UnsupportedFormatError
        When the content matches no supported format.
    """
    path = Path(path)
    if path.is_dir():
        return _folder_format(path)
    head = _read_head(path)
    ext = path.suffix.lower()
    fmt = _format_by_magic(path, head, ext)
    if fmt is not None:
        return fmt
    _refuse_by_name_or_magic(path, head, ext)
    return _video_format(path, head, ext)


def _folder_format(path: Path) -> str:
    """The format of a folder clip: a ROS 2 bag, a TUM sequence, ``rgb/`` frames or an Open3D dataset."""
    names = [p.relative_to(path).as_posix() for p in path.rglob("*") if p.is_file()]
    layout = _zip_layout(names)
    if layout in ("ros2-bag", "tum", "zip-frames", "open3d"):
        return layout
    raise UnsupportedFormatError(f"{path.name}/: folder holds no clip ({_SUPPORTED})")


def _read_head(path: Path) -> bytes:
    """The first 64 bytes of the file; an unreadable or empty file is a :class:`ClipError`."""
    try:
        with path.open("rb") as fh:
            head = fh.read(64)
    except OSError as exc:
        raise ClipError(f"cannot read {path.name}: {exc.strerror or exc}") from exc
    if not head:
        raise ClipError(f"{path.name} is empty (0 bytes); upload the clip again")
    return head


def _format_by_magic(path: Path, head: bytes, ext: str) -> str | None:
    """The format that the file's magic bytes name (a bag, or a zip by its layout), else None.

    A bag of an unsupported version, a corrupt zip or a zip of no clip layout raises.
    """
    if head.startswith(b"#ROSBAG V2.0"):
        return "ros1-bag"
    if head.startswith(b"#ROSBAG V"):
        version = head[9:12].decode("ascii", "replace")
        raise UnsupportedFormatError(
            f"{path.name}: ROS bag format version {version} is not supported; migrate it to v2.0 with "
            "`rosbag fix`"
        )
    if head.startswith(b"\x89MCAP0\r\n"):
        return "ros2-bag"
    if head.startswith(b"SQLite format 3\x00"):
        return "ros2-bag"
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return _zip_format(path, ext)
    return None


def _zip_format(path: Path, ext: str) -> str:
    """The clip layout inside the zip archive at ``path`` (see :func:`_zip_layout`)."""
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except ZIP_ERRORS as exc:
        kind = "npz" if ext == ".npz" else "zip"
        raise ClipError(
            f"{kind}: {path.name} is a zip archive but is corrupt or truncated ({exc}); upload it again"
        ) from exc
    layout = _zip_layout(names)
    if layout is None:
        listing = ", ".join(sorted({n.split("/", 1)[0] for n in visible(names)})[:8]) or "nothing"
        raise UnsupportedFormatError(
            f"{path.name}: zip holds no clip layout (found: {listing}); {_SUPPORTED}"
        )
    return layout


def _refuse_by_name_or_magic(path: Path, head: bytes, ext: str) -> None:
    """Refuse what is not a video before FFmpeg probes it: a lone ``.npy`` array or image, or a file
    named as a bag or an archive that lacks the format's magic bytes."""
    if head.startswith(b"\x93NUMPY"):
        raise UnsupportedFormatError(
            f"{path.name}: a single .npy array is not a clip; save an .npz with rgb=(T, H, W, 3) and fps"
        )
    if ext == ".bag":
        raise ClipError(f"ros1-bag: {path.name} does not start with '#ROSBAG V2.0'; it is not a ROS 1 bag")
    if ext in (".mcap", ".db3"):
        raise ClipError(f"ros2-bag: {path.name} has no MCAP or SQLite header; it is not a ROS 2 bag")
    if ext in (".npz", ".zip"):
        raise ClipError(f"{ext[1:]}: {path.name} is not a zip archive (it starts with {head[:8]!r})")
    if head.startswith((b"\x89PNG", b"\xff\xd8\xff")):
        raise UnsupportedFormatError(
            f"{path.name}: a single image is not a clip; zip the frames as rgb/*.png (and depth/*.png)"
        )


def _video_format(path: Path, head: bytes, ext: str) -> str:
    """``k4a-mkv`` or ``video`` when FFmpeg finds a video stream; else why the file is not a clip."""
    why = _probe_video(path)
    if why is None:
        if head.startswith(_EBML_MAGIC):
            from workers.pipeline.clipio.mkv import is_k4a_recording

            if is_k4a_recording(path):
                return "k4a-mkv"
        return "video"
    container = _container_kind(head)
    if container is not None:
        raise ClipError(
            f"video: {path.name} is an {container} file but is truncated or corrupt ({why}); "
            "upload the complete file"
        )
    if ext in _VIDEO_EXTS:
        raise ClipError(
            f"video: {path.name} has a video extension but its content is not a readable video "
            f"(starts with {head[:12]!r}); upload the camera's original file"
        )
    raise UnsupportedFormatError(f"{path.name}: not a clip format Eigenscope reads ({_SUPPORTED})")


def open_clip(
    path: str | Path,
    *,
    overrides: ClipOverrides | None = None,
    limits: ReadLimits | None = None,
    depth: str | Path | None = None,
    scratch_dir: str | Path | None = None,
) -> ClipReader:
    """Open a clip of any supported format for streaming.

    Parameters
    ----------
    path : path-like
        The clip (see :func:`detect_format` for formats).
    overrides : ClipOverrides, optional
        User-given metadata (fps, intrinsics, depth scale, bag topics); each given field wins over the file.
    limits : ReadLimits, optional
        Caps on frames, pixels, archive entries and decompressed size.
    depth : path-like, optional
        Depth companion of a video: an ``.npz`` with ``depth`` (T, H, W) or a zip/folder of 16-bit depth
        PNGs, one per video frame. Only for videos.
    scratch_dir : path-like, optional
        Where a zipped ROS 2 bag is unpacked (a private subfolder removed on close); default: the system
        temporary folder.

    Returns
    -------
    ClipReader
        Use as a context manager; ``reader.info`` describes the clip, ``reader.frames()`` streams
        :class:`~workers.pipeline.clipio.types.Frame` objects (RGB uint8 (H, W, 3), depth float32 metres
        (H, W) or None, timestamp in seconds).
    """
    from workers.pipeline.clipio.frames import FramesClip
    from workers.pipeline.clipio.mkv import K4aClip
    from workers.pipeline.clipio.npz import NpzClip
    from workers.pipeline.clipio.open3d import Open3dClip
    from workers.pipeline.clipio.rosbag import BagClip
    from workers.pipeline.clipio.video import VideoClip

    limits = limits or ReadLimits()
    fmt = detect_format(path)
    if depth is not None and fmt != "video":
        raise ParameterError(
            f"a depth companion applies only to video clips; {Path(path).name} is {fmt}, which carries "
            "its own depth"
        )
    if fmt == "npz":
        return NpzClip(path, overrides=overrides, limits=limits)
    if fmt in ("zip-frames", "tum"):
        return FramesClip(path, overrides=overrides, limits=limits)
    if fmt == "open3d":
        return Open3dClip(path, overrides=overrides, limits=limits)
    if fmt == "k4a-mkv":
        return K4aClip(path, overrides=overrides, limits=limits)
    if fmt == "video":
        archive = None
        if _is_zip(Path(path)):
            archive = Archive(path, "video", limits)
        return VideoClip(path, overrides=overrides, limits=limits, depth=depth, archive=archive)
    if fmt in ("ros1-bag", "ros2-bag"):
        return BagClip(path, fmt=fmt, overrides=overrides, limits=limits, scratch_dir=scratch_dir)
    raise UnsupportedFormatError(f"{Path(path).name}: format {fmt!r} has no reader")  # pragma: no cover
