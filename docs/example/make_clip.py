"""Write the README's example clip, ``docs/example/spring.zip``, and its truth, ``spring.truth.json``.

    python docs/example/make_clip.py

A rendered spring-mass object (6 Hz, 0.5 kg, held by 10 N and released at frame 8; 320x240, 30 fps,
96 frames) as a zip of JPEG colour frames, 16-bit PNG depth frames (millimetres) and ``camera.json``
(frame rate, intrinsics, depth scale): about 2 MB, where the same clip as an npz bundle takes 25 MB. The
depth is rendered without sensor noise (noise does not compress) and the colour is JPEG at quality 85.
Everything is seeded: the same files every time. ``tests/unit/cli/test_readme.py`` analyses it and
checks the README's sample output.
"""

from __future__ import annotations

import json
import sys
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

import eigenscope  # noqa: E402, F401 - one BLAS thread, before numpy
from workers.pipeline.synth import Scene, SceneObject, render  # noqa: E402

WIDTH, HEIGHT, FRAMES, FPS = 320, 240, 96, 30.0


def main() -> int:
    import cv2

    obj = SceneObject(
        center_px=(WIDTH / 2, HEIGHT / 2),
        size_px=(70.0, 55.0),
        depth_m=1.0,
        frequency_hz=6.0,
        damping_ratio=0.03,
        mass_kg=0.5,
        force_n=10.0,
        release_frame=8,
    )
    scene = Scene(
        width=WIDTH,
        height=HEIGHT,
        frames=FRAMES,
        fps=FPS,
        background_depth_m=2.0,
        objects=(obj,),
        seed=0,
        depth_noise_m=0.0,
    )
    clip = render(scene)
    out = HERE / "spring.zip"
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as zf:

        def add(name: str, data: bytes) -> None:  # a fixed date: the same bytes every time
            zf.writestr(zipfile.ZipInfo(name, date_time=(2026, 12, 2, 0, 0, 0)), data)

        for i, (rgb, depth) in enumerate(zip(clip.rgb, clip.depth, strict=True)):
            ok, jpg = cv2.imencode(".jpg", rgb[:, :, ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, 85])
            assert ok
            add(f"rgb/{i:06d}.jpg", bytes(jpg))
            ok, png = cv2.imencode(".png", depth)
            assert ok
            add(f"depth/{i:06d}.png", bytes(png))
        fx, fy, cx, cy = clip.intrinsics
        camera = {"fps": FPS, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "depth_scale": 0.001}
        add("camera.json", json.dumps(camera).encode())
    (HERE / "spring.truth.json").write_text(json.dumps(clip.truth, indent=2) + "\n")
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB) and spring.truth.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
