"""`stratamap view` and report.html in a real browser (headless Debian Chromium driven by Playwright).

The viewer is started as a user starts it (`stratamap view OUT --port N`) on the demo map and on a small
kitchen map with articulated completions; the tests check that the 3D canvas is drawn, that the control
panel lists every layer, and that moving a joint slider (opening a door) changes the picture. The report
test opens the demo run's report.html from disk and finds every figure rendered and every object of the
saved map in its table. Skipped only when Chromium or Playwright is missing (`make test` installs both).
"""

from __future__ import annotations

import io
import queue
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from stratamap.core.config import load_pipeline
from stratamap.core.map.layers import LayeredMap
from stratamap.core.pipeline import Pipeline
from tests.conftest import REPO

CHROMIUM = Path("/usr/bin/chromium")
if not CHROMIUM.is_file():
    pytest.skip(
        f"browser tests need Debian's Chromium at {CHROMIUM} (apt-get install chromium)", allow_module_level=True
    )
sync_api = pytest.importorskip("playwright.sync_api", reason="browser tests need playwright (pip install playwright)")

BROWSER_FLAGS = [
    "--no-sandbox",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-quic",
    # WebGL without a GPU: ANGLE on SwiftShader, which headless Chromium only allows when asked
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
]
VIEWPORT = {"width": 1280, "height": 800}
LAYER_WORDS = ("geometry", "semantics", "instances", "completions", "contact graph", "occupancy", "costmap")
#: The mapping and completion stages of configs/kitchen.yaml (its exporters add nothing to a map).
KITCHEN_STAGES = ("oracle", "tsdf", "occupancy", "contact_graph", "icp_match")


# --------------------------------------------------------------------------------------------
# Maps (small runs of the shipped pipelines)


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory) -> Path:
    """configs/demo.yaml with few, small frames."""
    out = tmp_path_factory.mktemp("browser-demo") / "run"
    small = ["source.params.frames=12", "source.params.scene.camera={width: 160, height: 120}"]
    Pipeline(load_pipeline(REPO / "configs" / "demo.yaml", small)).run(out)
    return out


@pytest.fixture(scope="module")
def kitchen_out(tmp_path_factory) -> Path:
    """configs/kitchen.yaml's scene and stages up to icp_match (which completes fridges, ovens, counters and
    cabinets with articulated models), on 12 frames of 160 x 120 and 4 cm voxels."""
    folder = tmp_path_factory.mktemp("browser-kitchen")
    config = yaml.safe_load((REPO / "configs" / "kitchen.yaml").read_text())
    scene = yaml.safe_load((REPO / "configs" / "scenes" / "kitchen.yaml").read_text())
    scene["camera"] = {**scene["camera"], "width": 160, "height": 120}
    config["source"]["params"] = {"scene": scene, "frames": 12}
    config["stages"] = [s for s in config["stages"] if s["plugin"] in KITCHEN_STAGES]
    next(s for s in config["stages"] if s["plugin"] == "tsdf")["params"] = {"voxel_size": 0.04}
    path = folder / "kitchen.yaml"
    path.write_text(yaml.safe_dump(config))
    out = folder / "run"
    Pipeline(load_pipeline(path)).run(out)
    m = LayeredMap.load(out / "map")
    assert any(i.completion is not None and i.completion.joints for i in m.instances), "no articulated completion"
    return out


# --------------------------------------------------------------------------------------------
# Browser and viewer


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    with sync_api.sync_playwright() as playwright:
        context = playwright.chromium.launch_persistent_context(
            str(tmp_path_factory.mktemp("chromium-profile")),  # a fresh profile: no state from earlier runs
            executable_path=str(CHROMIUM),
            headless=True,
            args=BROWSER_FLAGS,
            viewport=VIEWPORT,
        )
        yield context
        context.close()


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _as_from_a_terminal() -> None:
    """Ctrl-C reaches the viewer as it does from a terminal, even when the suite itself runs in the
    background (a non-interactive shell starts background jobs with SIGINT ignored, and children
    inherit that)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class ViewerProcess:
    """`stratamap view OUT` as a subprocess; ``url`` is the address it printed."""

    def __init__(self, out: Path, timeout: float = 90.0):
        command = [sys.executable, "-m", "stratamap.core.cli", "view", str(out), "--port", str(_free_port())]
        self.proc = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, preexec_fn=_as_from_a_terminal
        )
        self.lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        self.output: list[str] = []
        deadline = time.monotonic() + timeout
        self.url = ""
        while not self.url:
            if self.proc.poll() is not None and self.lines.empty():
                raise AssertionError(f"stratamap view exited with {self.proc.returncode}: {''.join(self.output)}")
            try:
                line = self.lines.get(timeout=max(0.1, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"no URL from stratamap view in {timeout} s: {''.join(self.output)}") from None
            self.output.append(line)
            found = re.search(r"stratamap view: (http://\S+)", line)
            self.url = found.group(1) if found else ""

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line)

    def stop(self) -> int:
        """Ctrl-C, as a user stops it; returns the exit status."""
        self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


def _canvas_png(page) -> bytes:
    """A screenshot of the 3D view (the largest canvas on the page)."""
    canvases = page.locator("canvas")
    areas = [
        (box["width"] * box["height"], i) for i in range(canvases.count()) if (box := canvases.nth(i).bounding_box())
    ]
    return canvases.nth(max(areas)[1]).screenshot()


def _pixels(png: bytes) -> np.ndarray:
    """The 3D view's pixels where only the scene is drawn: the middle of the canvas, clear of the control panel
    on the right and of notices at the top left (HTML over the canvas, which a canvas screenshot includes)."""
    from PIL import Image

    pixels = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)
    height, width = pixels.shape[:2]
    return pixels[int(0.25 * height) : int(0.95 * height), int(0.25 * width) : int(0.72 * width)]


def _settled(page, timeout: float = 30.0, since: np.ndarray | None = None, steady: int = 2) -> np.ndarray:
    """The canvas once ``steady`` + 1 screenshots half a second apart agree (the scene has arrived and
    been drawn; on a busy machine an update can pause half-way for half a second); with ``since``, once
    it has first changed from that picture (a slider's update goes to the viewer's server and back,
    later on a busy machine; until then the old picture is steady too)."""
    deadline = time.monotonic() + timeout
    previous = _pixels(_canvas_png(page))
    while since is not None and np.array_equal(previous, since) and time.monotonic() < deadline:
        time.sleep(0.25)
        previous = _pixels(_canvas_png(page))
    agreed = 0
    while time.monotonic() < deadline:
        time.sleep(0.5)
        current = _pixels(_canvas_png(page))
        agreed = agreed + 1 if np.array_equal(current, previous) else 0
        if agreed >= steady:
            return current
        previous = current
    return previous


def _assert_drawn(pixels: np.ndarray) -> None:
    """Not blank: more than a background colour, with many colours (shading, scan colours) and real contrast."""
    flat = pixels.reshape(-1, 3)
    colors, counts = np.unique(flat, axis=0, return_counts=True)
    background_share = counts.max() / len(flat)
    assert len(colors) > 200, f"only {len(colors)} colours in the canvas"
    assert background_share < 0.97, f"{background_share:.1%} of the canvas is one colour"
    assert flat.std(axis=0).max() > 12, f"canvas contrast {flat.std(axis=0)}"


@dataclass
class OpenedViewer:
    """`stratamap view` on one map, with a browser page showing it and the page's first full picture."""

    out: Path
    viewer: ViewerProcess
    page: Any
    pixels: np.ndarray
    screenshot: Path
    requests: list[str]


def _opened(out: Path, browser, shots: Path):
    viewer = ViewerProcess(out)
    try:
        page = browser.new_page()
        requests: list[str] = []
        page.on("request", lambda request: requests.append(request.url))
        page.goto(viewer.url)
        page.get_by_text("stratamap map").wait_for(timeout=60_000)
        page.wait_for_selector("canvas", timeout=60_000)
        pixels = _settled(page)
        page.screenshot(path=str(shots / "first.png"))
        yield OpenedViewer(out, viewer, page, pixels, shots / "first.png", requests)
        page.close()
    finally:
        viewer.stop()


@pytest.fixture(scope="module")
def demo_view(demo_out, browser, tmp_path_factory):
    yield from _opened(demo_out, browser, tmp_path_factory.mktemp("demo-view"))


@pytest.fixture(scope="module")
def kitchen_view(kitchen_out, browser, tmp_path_factory):
    yield from _opened(kitchen_out, browser, tmp_path_factory.mktemp("kitchen-view"))


@pytest.mark.parametrize("which", ["demo", "kitchen"])
def test_viewer_draws_the_map_and_lists_every_layer(which, request):
    opened: OpenedViewer = request.getfixturevalue(f"{which}_view")
    assert opened.screenshot.stat().st_size > 10_000
    _assert_drawn(opened.pixels)
    text = opened.page.locator("body").inner_text()
    missing = [word for word in LAYER_WORDS if word not in text.lower()]
    assert not missing, f"layer controls lack {missing}"
    assert "colour points by" in text and "objects shown as" in text
    m = LayeredMap.load(opened.out / "map")
    assert f"{len(m.instances)} objects" in text
    elsewhere = [url for url in opened.requests if not url.startswith((opened.viewer.url, "blob:", "data:"))]
    assert not elsewhere, f"the viewer fetched from elsewhere (it must work offline): {elsewhere}"


def _joint_label(page):
    """The label of a joint slider, a door hinge of the largest appliance if there is one."""
    labels = page.locator("label")
    texts = [labels.nth(i).inner_text().replace("\n", "") for i in range(labels.count())]
    joints = [(t, i) for i, t in enumerate(texts) if re.fullmatch(r"[a-z_]+ \d+: \w+", t)]
    assert joints, f"no joint sliders among the labels {texts}"
    for prefix in ("fridge", "oven", "counter", ""):
        for text, i in joints:
            if text.startswith(prefix) and "hinge" in text:
                return labels.nth(i), text
    return labels.nth(joints[0][1]), joints[0][0]


def test_moving_a_joint_slider_opens_the_part(kitchen_view, tmp_path):
    page, closed = kitchen_view.page, kitchen_view.pixels
    label, name = _joint_label(page)
    slider = page.locator(f'[id="{label.get_attribute("for")}"] [role="slider"]')
    assert float(slider.get_attribute("aria-valuenow")) == 0.0
    slider.focus()
    page.keyboard.press("End")  # the joint's upper limit: the door wide open
    assert float(slider.get_attribute("aria-valuenow")) == float(slider.get_attribute("aria-valuemax")) > 0
    opened = _settled(page, since=closed)
    page.screenshot(path=str(tmp_path / "opened.png"))
    changed = np.abs(opened - closed).max(axis=2) > 30
    assert changed.mean() > 0.002, f"moving {name} changed {changed.mean():.3%} of the picture"
    page.keyboard.press("Home")  # closed again: the picture comes back
    again = _settled(page, since=opened)
    assert (np.abs(again - closed).max(axis=2) > 30).mean() < changed.mean() / 4


def test_ctrl_c_stops_the_viewer(demo_view):
    assert demo_view.viewer.stop() == 0, "".join(demo_view.viewer.output)


def test_kitchen_models_at_rest_sit_where_the_map_saved_their_parts(kitchen_out):
    """The viewer's forward kinematics, with every joint at 0, reproduces the saved part poses of the real
    completions (so a slider at 0 shows the model as the completer placed it)."""
    from stratamap.core.viewer.scene import part_poses

    articulated = [i.completion for i in LayeredMap.load(kitchen_out / "map").instances if i.completion is not None]
    articulated = [c for c in articulated if c.joints]
    assert {j.type for c in articulated for j in c.joints} >= {"revolute", "prismatic"}
    for completion in articulated:
        rest = part_poses(completion)
        for part in completion.parts:
            np.testing.assert_allclose(rest[part.name], part.pose, atol=1e-9)


def test_report_html_shows_every_figure_and_every_object(demo_out, browser):
    page = browser.new_page()
    page.goto((demo_out / "report.html").resolve().as_uri())
    page.wait_for_load_state("load")
    images = page.locator("img")
    assert images.count() == 3  # by class, by instance, occupancy layers
    for i in range(images.count()):
        size = images.nth(i).evaluate("img => [img.complete, img.naturalWidth, img.naturalHeight]")
        assert size[0] and size[1] > 100 and size[2] > 100, (images.nth(i).get_attribute("alt"), size)
    assert "not drawn" not in page.locator("body").inner_text()
    header = [h.strip() for h in page.locator("table.objects thead th").all_inner_texts()]
    rows = page.locator("table.objects tbody tr")
    shown = {}
    for i in range(rows.count()):
        cells = [c.strip() for c in rows.nth(i).locator("td").all_inner_texts()]
        shown[int(cells[header.index("id")])] = cells[header.index("class")]
    saved = LayeredMap.load(demo_out / "map")
    assert shown == {inst.id: inst.class_name for inst in saved.instances}
    assert len(shown) >= 4
    page.close()
