"""The web page at ``/`` driven by a real browser against a real ``eigenscope serve``.

Screenshots land in ``test-artifacts/``. The README's copies in ``docs/images/`` are written when they are
missing or when ``EIGENSCOPE_UPDATE_DOCS_IMAGES=1`` (so an ordinary run leaves the checkout clean).
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import service_harness as h

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

IMAGE_NAME = re.compile(r"\.(png|jpe?g|gif|webp|svg)$", re.IGNORECASE)
DOCS_IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images"
API_KEY = "e2e-page-key-0123456789abcdef"


class Watch:
    """Console errors, page errors and every request a page makes."""

    def __init__(self, page: Any, base_url: str) -> None:
        self.base_url = base_url
        self.errors: list[str] = []
        self.requests: list[tuple[str, str]] = []
        page.on("pageerror", lambda exc: self.errors.append(f"page error: {exc}"))
        page.on("console", self._console)
        page.on("request", lambda req: self.requests.append((req.method, req.url)))

    def _console(self, message: Any) -> None:
        # A refused request is logged by the browser as a console error; those are expected in some tests.
        if message.type == "error" and "Failed to load resource" not in message.text:
            self.errors.append(f"console: {message.text}")

    def foreign(self) -> list[str]:
        return [
            url for _m, url in self.requests if not url.startswith((self.base_url + "/", "blob:", "data:"))
        ]

    def count(self, method: str, path: str) -> int:
        return sum(1 for m, url in self.requests if m == method and url == self.base_url + path)


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    context = browser.new_context(viewport={"width": 1280, "height": 900}, device_scale_factor=1)
    context.set_default_timeout(30_000)
    page = context.new_page()
    yield page
    context.close()


def number(text: str) -> float:
    return float(text.strip().replace(",", ""))


def save_screenshot(page: Any, artifacts_dir: Path, name: str, *, docs: bool = False, **options: Any) -> Path:
    """Save a screenshot to ``test-artifacts/``; with ``docs``, also the README's copy (palette PNG)."""
    path = artifacts_dir / name
    page.screenshot(path=str(path), **options)
    docs_copy = DOCS_IMAGES / name
    if docs and (not docs_copy.exists() or os.environ.get("EIGENSCOPE_UPDATE_DOCS_IMAGES") == "1"):
        from PIL import Image

        DOCS_IMAGES.mkdir(parents=True, exist_ok=True)
        with Image.open(path) as image:
            image.convert("RGB").quantize(colors=256, dither=Image.Dither.NONE).save(docs_copy, optimize=True)
    return path


def watch_upload_progress(page: Any) -> None:
    """Record every value the upload progress bar takes."""
    page.evaluate(
        """() => {
            window.__uploadValues = [];
            const bar = document.getElementById("upload-bar");
            new MutationObserver(() => window.__uploadValues.push(bar.value))
                .observe(bar, { attributes: true, attributeFilter: ["value"] });
        }"""
    )


def wait_for_images(page: Any) -> list[dict[str, Any]]:
    """Wait until every result image has loaded or failed; return what the browser sees of each."""
    page.wait_for_function(
        """() => [...document.querySelectorAll('#result img[data-artifact]')]
                 .every(img => img.dataset.loaded === 'true' || img.dataset.loaded === 'error')"""
    )
    images: list[dict[str, Any]] = page.eval_on_selector_all(
        "#result img[data-artifact]",
        """imgs => imgs.map(img => ({
            name: img.dataset.artifact, loaded: img.dataset.loaded, alt: img.alt,
            width: img.naturalWidth, height: img.naturalHeight, complete: img.complete,
            src: img.currentSrc,
            shown: img.getBoundingClientRect().width,
            room: img.closest("figure").getBoundingClientRect().width,
        }))""",
    )
    return images


def test_upload_through_the_page_shows_the_numbers_and_every_image(
    page: Any, live: h.LiveService, page_clip: tuple[Path, dict[str, Any]], artifacts_dir: Path
) -> None:
    from playwright.sync_api import expect

    clip, truth = page_clip
    obj = truth["objects"][0]
    assert obj["spec"]["excitation"] == "step_release"
    watch = Watch(page, live.base_url)

    page.goto(live.base_url + "/")
    expect(page.get_by_role("heading", name="New analysis")).to_be_visible()
    expect(page.get_by_role("link", name="API docs")).to_have_attribute("href", "docs")

    page.locator("#clip-file").set_input_files(str(clip))
    expect(page.locator("#file-chosen")).to_contain_text(clip.name)
    page.get_by_label("Held, then released").check()
    page.get_by_label("Holding force").fill(str(obj["spec"]["force_n"]))
    page.get_by_label("True frame rate").fill(str(truth["fps"]))
    save_screenshot(page, artifacts_dir, "page-upload.png", docs=True)

    watch_upload_progress(page)
    page.get_by_role("button", name="Upload and analyse").click()
    expect(page.locator("#upload-label")).to_contain_text("queued", timeout=60_000)
    values = page.evaluate("window.__uploadValues")
    assert values, "the upload progress bar never moved"
    assert max(values) == 100
    assert watch.count("POST", "/v1/clips") == 1
    assert watch.count("POST", "/v1/jobs") == 1

    # The live job list follows the job to its end; the result view opens by itself.
    job_item = page.locator("#jobs li").first
    job_id = job_item.get_attribute("data-job-id")
    assert job_id
    expect(job_item.locator(".badge")).to_have_text("Succeeded", timeout=180_000)
    expect(job_item.locator("progress")).to_have_attribute("value", "100")
    expect(job_item).to_contain_text(clip.name)
    result = page.locator("#result")
    expect(result.locator(".badge-succeeded")).to_be_visible()

    job = live.client.get(f"/v1/jobs/{job_id}").json()
    assert job["status"] == "succeeded", job
    assert job["parameters"]["fps"] == truth["fps"]

    # The numbers, with their units and uncertainties.
    table = result.locator(".object").first.locator("table")
    f_row = table.locator('tr[data-quantity="eigenfrequency_hz"]')
    f_shown = number(f_row.locator("td.value").inner_text())
    assert f_shown == pytest.approx(obj["eigenfrequency_hz"], rel=0.02)
    assert f_row.locator("td.unit-cell").inner_text() == "Hz"
    # A no-break space after the sign: it never parts from its number.
    assert f_row.locator("td.unc").inner_text().startswith("±\u00a0")
    expected = {
        "stiffness_n_per_m": ("N/m", obj["stiffness_n_per_m"]),
        "mass_kg": ("kg", obj["mass_kg"]),
        "amplitude_m": ("mm", obj["amplitude_m"] * 1000),
    }
    for quantity, (unit, value) in expected.items():
        row = table.locator(f'tr[data-quantity="{quantity}"]')
        assert number(row.locator("td.value").inner_text()) == pytest.approx(value, rel=0.1), quantity
        assert row.locator("td.unc").inner_text().startswith("±\u00a0"), quantity
        assert row.locator("td.unit-cell").inner_text() == unit, quantity
    for quantity in ("natural_frequency_hz", "damping_ratio", "pixel_count"):
        assert number(table.locator(f'tr[data-quantity="{quantity}"] td.value').inner_text()) > 0, quantity
    assert number(table.locator('tr[data-quantity="pixel_count"] td.value').inner_text()) == float(
        job["result"]["objects"][0]["pixel_count"]
    )
    # Each object says what its k and m were measured with, and where that came from.
    used = result.locator(".object").first.locator('.excitation-used[data-excitation-source="request"]')
    expect(used).to_contain_text(f"held force {obj['spec']['force_n']:g}")
    expect(used).to_contain_text("from request")
    summary = result.locator('.stat[data-quantity="eigenfrequency_hz"] .num')
    assert number(summary.inner_text()) == pytest.approx(obj["eigenfrequency_hz"], rel=0.02)
    for flag in job["result"]["quality"]:
        expect(result.locator(f'.flag[data-code="{flag["code"]}"]')).to_contain_text(flag["message"])
    if not job["result"]["quality"]:
        expect(result).to_contain_text("No quality warnings")

    # Every image the API lists, loaded, with alt text and a link to the file.
    artifacts: dict[str, str] = job["result"]["artifacts"]
    wanted = {url.rsplit("/", 1)[-1]: url for url in artifacts.values() if IMAGE_NAME.search(url)}
    assert "mask.png" in wanted
    images = wait_for_images(page)
    assert {i["name"] for i in images} == set(wanted)
    for image in images:
        assert image["loaded"] == "true", image
        assert image["complete"], image
        assert image["width"] > 0, image
        assert image["height"] > 0, image
        assert image["alt"], image
        # Shown whole: scaled to its card, neither collapsed nor cropped by it.
        assert 0.5 * image["room"] < image["shown"] <= image["room"], image
        link = result.locator(f'figure[data-artifact="{image["name"]}"] figcaption a')
        expect(link).to_have_attribute("href", wanted[image["name"]])
    expect(result.get_by_role("link", name="API documentation (/docs)")).to_have_attribute("href", "docs")

    result.scroll_into_view_if_needed()
    save_screenshot(page, artifacts_dir, "page-result.png", docs=True, full_page=True)
    assert watch.errors == []
    assert watch.foreign() == [], "the page must only talk to its own origin"


def test_the_page_checks_input_and_shows_the_apis_problems(
    page: Any,
    live: h.LiveService,
    page_clip: tuple[Path, dict[str, Any]],
    tmp_path: Path,
    artifacts_dir: Path,
) -> None:
    from playwright.sync_api import expect

    clip, _truth = page_clip
    watch = Watch(page, live.base_url)
    page.goto(live.base_url + "/")

    # The drop zone is reached with Tab; Enter and Space open the file picker. (The picker itself is not
    # opened here: under automation Chromium shows one file chooser per page load, so count the clicks.)
    page.evaluate(
        """() => {
            window.__pickerOpened = 0;
            const input = document.getElementById("clip-file");
            input.click = () => { window.__pickerOpened += 1; };
        }"""
    )
    for _ in range(12):
        page.keyboard.press("Tab")
        if page.evaluate("document.activeElement.id") == "dropzone":
            break
    expect(page.locator("#dropzone")).to_be_focused()
    page.keyboard.press("Enter")
    page.keyboard.press(" ")
    assert page.evaluate("window.__pickerOpened") == 2
    page.reload()

    # Every control has an accessible name (the drop zone and the hidden file input included).
    unnamed = page.evaluate(
        """() => [...document.querySelectorAll("input, select, button, textarea, [role=button]")]
              .filter(e => !(e.labels && e.labels.length) && !e.getAttribute("aria-label")
                           && !e.getAttribute("aria-labelledby") && !e.textContent.trim())
              .map(e => e.outerHTML.slice(0, 80))"""
    )
    assert unnamed == []

    # Nothing chosen: the page says what is missing and sends nothing.
    page.get_by_role("button", name="Upload and analyse").click()
    expect(page.locator("#clip-file-error")).to_contain_text("Choose a clip file")
    expect(page.locator("#force_n-error")).to_be_visible()
    expect(page.get_by_label("Holding force")).to_have_attribute("aria-invalid", "true")
    assert watch.count("POST", "/v1/clips") == 0

    # A file dropped on the drop zone is chosen: its name is shown and its error goes away.
    bad = tmp_path / "notes.npz"
    bad.write_text("these are notes, not a clip\n")
    transfer = page.evaluate_handle(
        """text => {
            const transfer = new DataTransfer();
            transfer.items.add(new File([text], "notes.npz", { type: "application/octet-stream" }));
            return transfer;
        }""",
        bad.read_text(),
    )
    page.dispatch_event("#dropzone", "dragenter", {"dataTransfer": transfer})
    expect(page.locator("#dropzone")).to_have_class(re.compile(r"\bdragover\b"))
    page.dispatch_event("#dropzone", "drop", {"dataTransfer": transfer})
    expect(page.locator("#dropzone")).not_to_have_class(re.compile(r"\bdragover\b"))
    expect(page.locator("#file-chosen")).to_contain_text("notes.npz")
    expect(page.locator("#clip-file-error")).to_be_hidden()
    assert page.evaluate("document.getElementById('clip-file').files[0].name") == "notes.npz"

    # Numbers must be positive.
    page.get_by_label("Holding force").fill("-3")
    page.get_by_label("True frame rate").fill("0")
    page.get_by_role("button", name="Upload and analyse").click()
    expect(page.locator("#force_n-error")).to_contain_text("greater than 0")
    expect(page.locator("#fps-error")).to_contain_text("greater than 0")
    expect(page.get_by_label("Holding force")).to_be_focused()
    assert watch.count("POST", "/v1/clips") == 0

    # A text file named .npz: the API refuses it and the page shows the API's own problem.
    with bad.open("rb") as fh:
        refused = live.client.post("/v1/clips", files={"file": (bad.name, fh, "application/octet-stream")})
    assert refused.status_code in (415, 422)
    problem = refused.json()
    page.get_by_label("Holding force").fill("5")
    page.get_by_label("True frame rate").fill("")
    page.get_by_role("button", name="Upload and analyse").click()
    box = page.locator("#form-problem")
    expect(box).to_be_visible()
    expect(box).to_contain_text(problem["title"])
    expect(box).to_contain_text(f"HTTP {refused.status_code}")
    expect(box).to_contain_text(problem["detail"].split(":", 1)[-1].strip())
    expect(page.locator("#clip-file-error")).to_be_visible()
    save_screenshot(page, artifacts_dir, "page-refused.png")

    # A parameter the API refuses for this clip: its field error lands on the field.
    page.locator("#clip-file").set_input_files(str(clip))
    page.get_by_text("More options").click()
    page.get_by_label("First frame").fill("100000")
    page.get_by_role("button", name="Upload and analyse").click()
    expect(page.locator("#start_frame-error")).to_contain_text("past the clip", timeout=60_000)
    expect(page.get_by_label("First frame")).to_have_attribute("aria-invalid", "true")
    expect(box).to_contain_text("parameters.start_frame")
    assert watch.count("POST", "/v1/clips") == 2

    # Fixed, the same clip is analysed without uploading it again.
    page.get_by_label("First frame").fill("")
    page.get_by_role("button", name="Upload and analyse").click()
    expect(page.locator("#upload-label")).to_contain_text("queued", timeout=60_000)
    expect(box).to_be_hidden()
    assert watch.count("POST", "/v1/clips") == 2
    expect(page.locator("#result .badge-succeeded")).to_be_visible(timeout=180_000)
    assert watch.errors == []
    assert watch.foreign() == []


def test_the_page_works_with_api_keys(
    browser: Any, tmp_path_factory: pytest.TempPathFactory, artifacts_dir: Path
) -> None:
    from playwright.sync_api import expect

    tmp = tmp_path_factory.mktemp("keys")
    clip = tmp / "small.npz"
    h.synth_clip(clip, **h.SMALL_CLIP)
    service = h.start_embedded(tmp, api_keys=API_KEY)
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    context.set_default_timeout(30_000)
    try:
        assert service.client.get("/v1/jobs").status_code == 401
        page = context.new_page()
        watch = Watch(page, service.base_url)
        page.goto(service.base_url + "/")

        # Without a key the page loads, says a key is needed and points at the field.
        jobs_problem = page.locator("#jobs-problem")
        expect(jobs_problem).to_contain_text("HTTP 401")
        expect(jobs_problem).to_contain_text("needs an API key")
        page.locator("#clip-file").set_input_files(str(clip))
        page.get_by_label("Holding force").fill(str(h.SMALL_CLIP["force_n"]))
        page.get_by_role("button", name="Upload and analyse").click()
        expect(page.locator("#form-problem")).to_contain_text("HTTP 401")
        expect(page.get_by_label("API key")).to_be_focused()

        # A wrong key is refused too.
        page.get_by_label("API key").fill("not-the-key-0123456789")
        page.get_by_role("button", name="Use", exact=True).click()
        page.get_by_role("button", name="Upload and analyse").click()
        expect(page.locator("#form-problem")).to_contain_text("HTTP 401")

        # With the key: upload, job, result and images (fetched with the key) all work.
        page.get_by_label("API key").fill(API_KEY)
        page.get_by_role("button", name="Use", exact=True).click()
        expect(jobs_problem).to_be_hidden()
        assert page.evaluate("sessionStorage.getItem('eigenscope.apiKey')") == API_KEY
        page.get_by_role("button", name="Upload and analyse").click()
        expect(page.locator("#result .badge-succeeded")).to_be_visible(timeout=180_000)
        images = wait_for_images(page)
        assert images
        for image in images:
            assert image["loaded"] == "true", image
            assert image["width"] > 0, image
            assert image["src"].startswith("blob:"), image
        f_text = page.locator('#result tr[data-quantity="eigenfrequency_hz"] td.value').inner_text()
        assert number(f_text) == pytest.approx(h.SMALL_CLIP["frequency_hz"], rel=0.02)

        # The key lives in this tab's session: a reload keeps it, a new tab (context) does not.
        page.reload()
        expect(page.get_by_label("API key")).to_have_value(API_KEY)
        expect(page.locator("#jobs li")).to_have_count(1)
        other = browser.new_context().new_page()
        other.goto(service.base_url + "/")
        expect(other.get_by_label("API key")).to_have_value("")
        other.context.close()
        assert watch.foreign() == []
    finally:
        context.close()
        service.stop()


#: Horizontal overflow a page at phone width must not hide: every element with an overflow other than
#: visible, and every table cell against its table's scroll box. Deliberate ellipses (the full text in a
#: title) and text for screen readers only (.visually-hidden) are allowed.
CLIPPED = """() => {
    const found = [];
    const root = document.documentElement;
    if (root.scrollWidth > root.clientWidth) found.push(`page ${root.scrollWidth} > ${root.clientWidth}`);
    for (const el of document.querySelectorAll("body *")) {
        const style = getComputedStyle(el);
        if (style.display === "none" || el.closest("[hidden], .visually-hidden")) continue;
        if (style.textOverflow === "ellipsis" && el.title) continue;
        const boxed = ["auto", "hidden", "scroll", "clip"].includes(style.overflowX);
        if (boxed && el.scrollWidth > el.clientWidth + 1) {
            found.push(`${el.tagName}.${el.className}: ${el.scrollWidth} > ${el.clientWidth}`);
        }
    }
    for (const cell of document.querySelectorAll("table.quantities td, table.quantities th")) {
        const box = cell.closest(".table-wrap").getBoundingClientRect();
        const r = cell.getBoundingClientRect();
        if (r.width && (r.right > box.right + 1 || r.left < box.left - 1)) {
            found.push(`cell ${cell.className || cell.tagName}: ${r.left}-${r.right} outside the table`);
        }
    }
    return found;
}"""

#: The colour (RGB) the browser shows at the first pixel of object 1 in the mask image.
MASK_COLOUR = """async () => {
    const img = document.querySelector('img[data-artifact="mask.png"]');
    const canvas = document.createElement("canvas");
    canvas.width = img.naturalWidth;
    canvas.height = img.naturalHeight;
    const ctx = canvas.getContext("2d");
    ctx.drawImage(img, 0, 0);
    const px = ctx.getImageData(0, 0, canvas.width, canvas.height).data;
    const colours = new Set();
    for (let i = 0; i < px.length; i += 4) colours.add(`${px[i]},${px[i + 1]},${px[i + 2]}`);
    return [...colours];
}"""


def test_each_job_has_its_own_url_and_the_page_fits_a_phone(
    browser: Any, live: h.LiveService, page_clip: tuple[Path, dict[str, Any]], artifacts_dir: Path
) -> None:
    from eigenscope_client import Client, StepRelease
    from playwright.sync_api import expect

    with Client(live.base_url) as client:
        first = client.analyze(page_clip[0], excitation=StepRelease(force_n=5.0), timeout=180)
        second = client.analyze(page_clip[0], timeout=180)
    assert first.status == second.status == "succeeded"
    context = browser.new_context(viewport={"width": 400, "height": 860}, device_scale_factor=1)
    context.set_default_timeout(30_000)
    page = context.new_page()
    watch = Watch(page, live.base_url)
    try:
        # A bookmarked job URL opens straight on that job.
        page.goto(f"{live.base_url}/jobs/{first.id}")
        expect(page.locator("#result-title")).to_contain_text(first.id[:8])
        expect(page.locator('#result [data-quantity="mass_kg"] td.unit-cell')).to_have_text("kg")
        wait_for_images(page)
        assert page.title() == f"Job {first.id[:8]} · Eigenscope"
        assert page.evaluate(CLIPPED) == []
        # The link opens on the headline; below it, every column of the table is in view (none cut off).
        expect(page.locator('#result .stat[data-quantity="eigenfrequency_hz"]')).to_be_in_viewport()
        unit = page.locator('#result [data-quantity="stiffness_n_per_m"] td.unit-cell')
        unit.scroll_into_view_if_needed()
        expect(unit).to_be_in_viewport(ratio=1)
        # The mask is a palette image: the browser shows object 1 in its colour on black.
        colours = page.evaluate(MASK_COLOUR)
        assert "0,0,0" in colours
        assert "255,127,14" in colours
        page.screenshot(path=str(artifacts_dir / "page-400px.png"), full_page=True)
        permalink = page.locator("#result-actions [data-permalink]")
        expect(permalink).to_have_attribute("href", f"{live.base_url}/jobs/{first.id}")

        # From the list, each job chosen gets its URL; Back walks through them to the list alone.
        page.goto(f"{live.base_url}/")
        expect(page.locator("#result")).to_be_hidden()
        page.locator(f'button[data-job-id="{first.id}"]').click()
        expect(page).to_have_url(f"{live.base_url}/jobs/{first.id}")
        page.locator(f'button[data-job-id="{second.id}"]').click()
        expect(page).to_have_url(f"{live.base_url}/jobs/{second.id}")
        expect(page.locator("#result-title")).to_contain_text(second.id[:8])
        page.go_back()
        expect(page).to_have_url(f"{live.base_url}/jobs/{first.id}")
        expect(page.locator("#result-title")).to_contain_text(first.id[:8])
        page.go_back()
        expect(page).to_have_url(f"{live.base_url}/")
        expect(page.locator("#result")).to_be_hidden()

        # A job that does not exist says so.
        page.goto(f"{live.base_url}/jobs/no-such-job")
        expect(page.locator("#result-body .problem")).to_contain_text("no job with id")
        assert watch.errors == []
        assert watch.foreign() == []
    finally:
        context.close()


#: A clip name as a lab's recording tool writes them: long, and without a space to break at.
LONG_NAME = "robot-arm-station-07_push-test_2026-01-01T12-00-00_object-0042_take-0003_colour-and-depth.npz"

#: For each quantity label of the result tables: the words broken across lines (none may be).
BROKEN_WORDS = """() => {
    const broken = [];
    for (const th of document.querySelectorAll("#result table.quantities tbody th")) {
        const text = th.firstChild;
        if (!text || text.nodeType !== Node.TEXT_NODE) continue;
        let at = 0;
        for (const word of text.textContent.split(" ")) {
            const range = document.createRange();
            range.setStart(text, at);
            range.setEnd(text, at + word.length);
            if (word && range.getClientRects().length > 1) broken.push(word);
            at += word.length + 1;
        }
    }
    return broken;
}"""
#: The uncertainty cells ("± 0.0021") that take more than one line.
WRAPPED_UNCERTAINTIES = """() => [...document.querySelectorAll("#result td.unc")]
    .filter(td => td.textContent && (() => {
        const range = document.createRange();
        range.selectNodeContents(td);
        const tops = new Set([...range.getClientRects()].map(r => Math.round(r.top)));
        return tops.size > 1;
    })())
    .map(td => td.textContent)"""


@pytest.fixture(scope="module")
def listed_on_a_phone(live: h.LiveService, page_clip: tuple[Path, dict[str, Any]]) -> dict[str, str]:
    """A job of a clip with a long name and the job of a live stream (``stream-<32 hex>.zip``), ended."""
    from eigenscope_client import Client, StepRelease, StreamSession
    from stream_helpers import scene_frames, send_scene, session_kwargs

    with Client(live.base_url) as client:
        clip = client.upload_clip(page_clip[0], filename=LONG_NAME)
        job = client.wait(client.create_job(clip.id, excitation=StepRelease(force_n=5.0)), timeout=180)
        assert job.status == "succeeded"
        scene = scene_frames(frames=40)
        with StreamSession(live.base_url, **session_kwargs(scene)) as session:
            send_scene(session, scene)
            session.finish(timeout_s=120)
        stream_job = client.wait(client.get_job(session.job_id), timeout=120)
        stream_clip = client.get_clip(stream_job.clip_id)
    assert stream_clip.filename == f"stream-{session.stream_id}.zip"
    return {"job": job.id, "stream_job": stream_job.id, "stream_name": stream_clip.filename}


@pytest.mark.parametrize("width", [360, 390, 400])
def test_the_page_fits_a_phone_with_long_names_listed(
    browser: Any, live: h.LiveService, listed_on_a_phone: dict[str, str], artifacts_dir: Path, width: int
) -> None:
    from playwright.sync_api import expect

    context = browser.new_context(viewport={"width": width, "height": 780}, device_scale_factor=1)
    context.set_default_timeout(30_000)
    page = context.new_page()
    watch = Watch(page, live.base_url)
    try:
        page.goto(live.base_url + "/")
        long_item = page.locator(f'button[data-job-id="{listed_on_a_phone["job"]}"] .job-name')
        stream_item = page.locator(f'button[data-job-id="{listed_on_a_phone["stream_job"]}"] .job-name')
        expect(long_item).to_have_text(LONG_NAME)
        expect(stream_item).to_have_text(listed_on_a_phone["stream_name"])
        assert page.evaluate(CLIPPED) == []
        upload = page.locator("#upload-card").bounding_box()
        assert upload is not None
        assert upload["x"] >= 0
        assert upload["x"] + upload["width"] <= width
        # Elided in the list, the whole name is there on hover (its title) and on focus (wrapped).
        expect(long_item).to_have_attribute("title", LONG_NAME)
        assert page.evaluate("el => el.scrollWidth > el.clientWidth", long_item.element_handle())
        page.locator(f'button[data-job-id="{listed_on_a_phone["job"]}"]').focus()
        page.keyboard.press("Shift+Tab")
        page.keyboard.press("Tab")  # keyboard focus: :focus-visible
        assert page.evaluate("el => el.scrollWidth <= el.clientWidth", long_item.element_handle())
        page.screenshot(path=str(artifacts_dir / f"page-{width}px-list.png"), full_page=True)

        # A job's own URL opens on its headline: the title and the summary cards are in view.
        page.goto(f"{live.base_url}/jobs/{listed_on_a_phone['job']}")
        expect(page.locator("#result .summary")).to_be_visible()
        wait_for_images(page)
        expect(page.locator("#jobs li").first).to_be_visible()  # the list above has filled
        expect(page.locator("#result-title")).to_contain_text(LONG_NAME)  # wrapped, not cut off
        expect(page.locator("#result-title")).to_be_in_viewport()
        expect(page.locator('#result .stat[data-quantity="eigenfrequency_hz"]')).to_be_in_viewport()
        assert page.evaluate(CLIPPED) == []
        assert page.evaluate(BROKEN_WORDS) == []
        assert page.evaluate(WRAPPED_UNCERTAINTIES) == []
        page.screenshot(path=str(artifacts_dir / f"page-{width}px-job.png"), full_page=True)
        assert watch.errors == []
    finally:
        context.close()


def test_image_alt_texts_describe_their_figures(
    page: Any, live: h.LiveService, listed_on_a_phone: dict[str, str]
) -> None:
    """Each image's alt text says what the API's own description of that artifact says it shows."""
    spec = json.loads((Path(__file__).resolve().parents[2] / "openapi" / "openapi.json").read_text())
    described = spec["components"]["schemas"]["Artifacts"]["properties"]
    page.goto(f"{live.base_url}/jobs/{listed_on_a_phone['job']}")
    images = {i["name"]: i["alt"] for i in wait_for_images(page)}
    keys = {
        "ringdown.png": ("ringdown", "spectrogram"),
        "displacement.png": ("displacement", "damped oscillation"),
        "spectrum.png": ("spectrum", "noise floor"),
        "frequency_map.png": ("frequency_map", "colour bar"),
        "overlay.png": ("overlay", "outlined"),
        "modes.png": ("mode_shapes", "arrows"),
        "modes.gif": ("mode_animation", "magnified shape"),
    }
    for name, (key, words) in keys.items():
        assert words in described[key]["description"].lower(), key
        assert words in images[name].lower(), (name, images[name])
