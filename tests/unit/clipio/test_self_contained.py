"""Clips cannot reach outside themselves: playlists, concatenation, manifests and containers off the
allow-list are refused with a clip error (422), whatever the file is called, alone or inside a zip; the
demuxer allow-list and the refusal of every other file are each enough on their own."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from workers.pipeline.clipio import open_clip
from workers.pipeline.clipio import video as video_module
from workers.pipeline.clipio import writers as w
from workers.pipeline.clipio.detect import detect_format
from workers.pipeline.errors import ClipError, UnsupportedFormatError


@pytest.fixture(scope="module")
def outside(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A readable video outside the uploads' folder (what a playlist would make the server read)."""
    rgb = np.random.default_rng(3).integers(0, 255, (20, 48, 64, 3), dtype=np.uint8)
    return w.write_video(tmp_path_factory.mktemp("secret") / "clip.ts", rgb, fps=30.0, codec="mpeg4")


def referring_files(target: Path, upload_dir: Path) -> dict[str, bytes]:
    """Files FFmpeg would read as pointers to ``target``: by absolute URL, by relative path, by list."""
    relative = Path("..") / target.parent.name / target.name
    hls = "#EXTM3U\n#EXT-X-TARGETDURATION:10\n#EXTINF:10,\n{}\n#EXT-X-ENDLIST\n"
    return {
        "abs.m3u8": hls.format(f"file://{target}").encode(),
        "bare.m3u8": hls.format(str(target)).encode(),
        "relative.m3u8": hls.format(relative.as_posix()).encode(),
        "playlist.mp4": hls.format(f"file://{target}").encode(),  # the extension lies
        "short.m3u8": f"#EXTM3U\n#EXTINF:10,\nfile://{target}\n".encode(),
        "list.ffconcat": f"ffconcat version 1.0\nfile '{target}'\n".encode(),
        "list.txt": f"ffconcat version 1.0\nfile '{relative.as_posix()}'\n".encode(),
        "manifest.mpd": (
            '<?xml version="1.0"?><MPD xmlns="urn:mpeg:dash:schema:mpd:2011" type="static">'
            f'<Period><AdaptationSet><Representation id="1"><BaseURL>file://{target}</BaseURL>'
            "</Representation></AdaptationSet></Period></MPD>"
        ).encode(),
        "session.sdp": b"v=0\r\no=- 0 0 IN IP4 127.0.0.1\r\ns=x\r\nc=IN IP4 127.0.0.1\r\n"
        b"m=video 5004 RTP/AVP 96\r\n",
    }


def test_playlists_and_lists_of_files_are_clip_errors(outside: Path, tmp_path: Path) -> None:
    uploads = tmp_path / "uploads"
    uploads.mkdir()
    (tmp_path / outside.parent.name).symlink_to(outside.parent)  # the relative forms resolve
    for name, data in referring_files(outside, uploads).items():
        path = uploads / name
        path.write_bytes(data)
        with pytest.raises(ClipError) as info, open_clip(path) as reader:
            list(reader.frames(0, 1))
        assert not isinstance(info.value, UnsupportedFormatError), name  # 422, not 415
        assert "names other files" in str(info.value), (name, str(info.value))
        assert str(outside) not in str(info.value)


def test_a_playlist_inside_a_zip_is_refused(outside: Path, tmp_path: Path) -> None:
    path = tmp_path / "wrapped.zip"
    hls = f"#EXTM3U\n#EXT-X-TARGETDURATION:10\n#EXTINF:10,\nfile://{outside}\n#EXT-X-ENDLIST\n"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("clip.mp4", hls)
    assert detect_format(path) == "video"
    with pytest.raises(ClipError, match="names other files"):
        open_clip(path)


def test_the_demuxer_allow_list_alone_refuses_a_playlist(
    outside: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without the recognition of playlist text, FFmpeg's own allow-list refuses the HLS demuxer before
    it parses a line."""
    monkeypatch.setattr(video_module, "referring_kind", lambda head: None)
    path = tmp_path / "x.m3u8"
    path.write_text(f"#EXTM3U\n#EXT-X-TARGETDURATION:10\n#EXTINF:10,\nfile://{outside}\n#EXT-X-ENDLIST\n")
    with pytest.raises(ClipError, match="not in a container Eigenscope reads"):
        video_module.open_video(path, path.name)


def test_no_other_file_opens_even_with_a_demuxer_that_would(
    outside: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Even a demuxer that reads other files (allowed here on purpose) cannot open one."""
    monkeypatch.setattr(video_module, "referring_kind", lambda head: None)
    path = tmp_path / "x.m3u8"
    path.write_text(f"#EXTM3U\n#EXT-X-TARGETDURATION:10\n#EXTINF:10,\nfile://{outside}\n#EXT-X-ENDLIST\n")
    with pytest.raises(ClipError, match="refers to another"):
        video_module.open_video(path, path.name, demuxers=("hls",))


def test_a_container_off_the_allow_list_is_refused(tmp_path: Path) -> None:
    """A real video, but in FFmpeg's NUT container, which is not on the list."""
    import av

    rgb = np.random.default_rng(4).integers(0, 255, (16, 32, 48, 3), dtype=np.uint8)
    path = tmp_path / "clip.nut"
    with av.open(str(path), mode="w", format="nut") as out:
        stream = out.add_stream("ffv1", rate=30)
        stream.width, stream.height, stream.pix_fmt = 48, 32, "bgr0"
        for frame in rgb:
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    with pytest.raises(ClipError) as info:
        open_clip(path)
    assert "not a clip format" in str(info.value) or "container" in str(info.value)


def test_a_codec_off_the_allow_list_is_refused(tmp_path: Path) -> None:
    """An allowed container holding a codec that is not on the list is refused before decoding."""
    import av

    path = tmp_path / "clip.avi"
    with av.open(str(path), mode="w", format="avi") as out:
        stream = out.add_stream("zmbv", rate=30)  # DOSBox's capture codec
        stream.width, stream.height, stream.pix_fmt = 48, 32, "bgr0"
        for _ in range(4):
            frame = av.VideoFrame.from_ndarray(np.zeros((32, 48, 3), np.uint8), format="rgb24")
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    with pytest.raises(ClipError, match="zmbv video stream, a codec Eigenscope does not decode"):
        open_clip(path)


def test_allowed_videos_still_read(tmp_path: Path) -> None:
    rgb = np.random.default_rng(6).integers(0, 255, (16, 32, 48, 3), dtype=np.uint8)
    for name, codec in (("c.mp4", "libx264"), ("c.mkv", "ffv1"), ("c.avi", "mjpeg"), ("c.ts", "mpeg4")):
        path = w.write_video(tmp_path / name, rgb, fps=30.0, codec=codec)
        with open_clip(path) as reader:
            assert len(list(reader.frames())) == 16, name
