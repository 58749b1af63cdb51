"""The web page shows a live stream's estimates as they arrive (real browser, real server and worker)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest
import service_harness as h

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "integration"))

from eigenscope_client import StreamSession
from stream_helpers import scene_frames, send_scene, session_kwargs

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


def test_the_page_shows_a_live_streams_estimates(browser: Any, live: h.LiveService) -> None:
    scene = scene_frames()
    session = StreamSession(live.base_url, **session_kwargs(scene))
    try:
        # Send frames until the first estimate, then hold the stream open while the page looks.
        send_scene(session, scene, stop=60)
        page = browser.new_page()
        page.goto(live.base_url + "/")
        selector = f'#streams li[data-stream-id="{session.stream_id}"]'
        item = page.locator(selector)
        item.wait_for(timeout=30_000)
        page.wait_for_function(
            "sel => (document.querySelector(sel)?.textContent || '').includes(' Hz')",
            arg=selector,
            timeout=30_000,
        )
        text = item.text_content() or ""
        assert "f = 4.4" in text or "f = 4.5" in text, text
        assert "frames" in text
        result = session.finish(timeout_s=120)
        assert result["objects"]
        page.close()
    finally:
        session.close()
