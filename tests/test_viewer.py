"""`ndfa view`: one line and exit code 2 where the desktop viewer cannot open, and `--web`: Rerun's
web viewer, opened in headless Chromium, draws the run's scene in the layout the .rrd carries."""

import base64
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).parents[1]
SAMPLE = ROOT / "recordings" / "sample"
CHROMIUM = Path(os.environ.get("NDFA_CHROMIUM", "/usr/bin/chromium"))  # Debian's package (scripts/setup.sh)
# Software WebGL: the web viewer renders on the CPU, which is why a page takes tens of seconds.
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
VIEWPORT = {"width": 1200, "height": 720}
LOAD_S = 80  # the page, the viewer's wasm and the first objects on 2 loaded cores: 20-30 s measured
SCREENSHOT_LOAD_S = 150  # the whole recording, streamed into a viewer that draws in software: ~100 s


def ndfa(*args: str, env: dict[str, str] | None = None, **kwargs) -> subprocess.CompletedProcess:
    """This checkout's `ndfa` (not the installed one), as a user runs it."""
    return subprocess.run([sys.executable, "-m", "ndfa.cli", *args], cwd=ROOT, capture_output=True, text=True,
                          env={**(env if env is not None else os.environ), "PYTHONPATH": str(ROOT)}, timeout=120,
                          **kwargs)


def free_port_pair() -> int:
    """A port P with P + 1 also free (`ndfa view --web` serves on both)."""
    for _ in range(50):
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        if port < 65535:
            with socket.socket() as probe:
                try:
                    probe.bind(("127.0.0.1", port + 1))
                    return port
                except OSError:
                    continue
    raise RuntimeError("no two free neighbouring ports")


@pytest.fixture
def rrd(tmp_path) -> Path:
    """A file with a .rrd name: the checks below fail before Rerun reads it."""
    path = tmp_path / "run.rrd"
    path.write_bytes(b"not read")
    return path


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the display variables are Linux's")
def test_without_a_display_the_viewer_points_to_web(rrd):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")}
    result = ndfa("view", str(rrd), env=env)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and str(rrd) in result.stderr and "--web" in result.stderr


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="an X display that is not there is Linux's")
def test_a_viewer_that_cannot_start_is_an_error(rrd):
    result = ndfa("view", str(rrd), env={**os.environ, "DISPLAY": ":97"})  # no X server answers there
    assert result.returncode == 2, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "could not start" in errors[0] and "--web" in errors[0]
    assert "Traceback" not in result.stderr


def test_a_busy_port_is_named(rrd):
    port = free_port_pair()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", port + 1))
        taken.listen()
        result = ndfa("view", str(rrd), "--web", "--port", str(port))
    assert result.returncode == 2
    assert f":{port + 1}" in result.stderr and "--port" in result.stderr and "Traceback" not in result.stderr


def test_the_recording_carries_its_layout(tmp_path):
    """What `rerun run.rrd` opens in: one 3-D world view, the two cameras, the log and the timings."""
    from rerun.chunk import RrdReader

    from ndfa.log.rerun_sink import RerunSink

    RerunSink(tmp_path / "run.rrd").close()
    reader = RrdReader(tmp_path / "run.rrd")
    (blueprint,) = reader.blueprints()
    views, overrides = {}, set()
    for chunk in reader.store(store=blueprint).stream().to_chunks():
        path = str(chunk.entity_path)
        if path.startswith("/view/") and path.count("/") == 2:
            batch = chunk.to_record_batch()
            views[batch.column("ViewBlueprint:display_name").to_pylist()[0][0]] = \
                batch.column("ViewBlueprint:class_identifier").to_pylist()[0][0]
        if "/overrides/" in path:
            overrides.add(path.split("/overrides", 1)[1].removesuffix("/visualizers"))
    assert sorted(views.values()) == ["2D", "2D", "3D", "TextLog", "TimeSeries"], views
    assert overrides == {"/source/tree/cells", "/target/tree/cells"}  # hidden: they cover the objects


def scene_pixels(screenshot: np.ndarray) -> tuple[int, int]:
    """Of the world view's region (the left two thirds, between the top bar and the time panel, where
    the blueprint puts it): how many pixels are strongly coloured, and over how many of its 6 x 6
    cells (30 such pixels or more) they spread. A blank view, its grid and a loading page are white
    and grey; Rerun's welcome page has one blue bar there (two cells); the scene's objects stand apart."""
    height, width, _ = screenshot.shape
    region = screenshot[int(0.08 * height):int(0.94 * height), :int(0.64 * width)].astype(int)
    coloured = (region.max(axis=-1) - region.min(axis=-1)) > 80
    rows, columns = (n // 6 * 6 for n in coloured.shape)
    cells = coloured[:rows, :columns].reshape(6, rows // 6, 6, columns // 6).sum(axis=(1, 3))
    return int(coloured.sum()), int((cells >= 30).sum())


def drew_the_scene(screenshot: np.ndarray) -> bool:
    """Enough coloured pixels (the objects' clouds: thousands of the region's 440 thousand), spread
    over the view (measured: 6-10 cells for the scene's first objects, 2 for the welcome page)."""
    count, cells = scene_pixels(screenshot)
    return count >= 800 and cells >= 4


def test_the_screenshot_check_tells_a_scene_from_an_empty_view():
    page = np.full((720, 1200, 3), 250, np.uint8)
    page[::40] = page[:, ::40] = 200  # the grid
    assert not drew_the_scene(page)
    welcome = page.copy()
    welcome[70:95, 10:190] = (40, 110, 230)  # the welcome page's selected "Welcome to rerun"
    assert not drew_the_scene(welcome)
    scene = page.copy()
    for row, column in [(200, 150), (300, 400), (450, 250), (350, 600), (550, 500)]:
        scene[row:row + 20, column:column + 15] = (80, 140, 255)  # five mugs' clouds
    assert drew_the_scene(scene)


@pytest.fixture(scope="module")
def sample_rrd(tmp_path_factory) -> Path:
    """`ndfa detect --log` of the sample pair, every other frame (the layout is what is tested)."""
    path = tmp_path_factory.mktemp("view") / "sample.rrd"
    result = ndfa("detect", str(SAMPLE / "source.mcap"), str(SAMPLE / "target.mcap"), "--frame-step", "2",
                  "--threads", "1", "--log", str(path), env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert result.returncode == 0, result.stderr
    return path


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_web_viewer_draws_the_scene(sample_rrd, tmp_path):
    from PIL import Image

    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("Playwright is not installed (the dev extra; scripts/setup.sh installs it)")
    if not CHROMIUM.is_file():
        pytest.skip(f"no Chromium at {CHROMIUM} (scripts/setup.sh installs Debian's chromium; or set NDFA_CHROMIUM)")

    port = free_port_pair()
    server = subprocess.Popen([sys.executable, "-m", "ndfa.cli", "view", str(sample_rrd), "--web", "--port", str(port)],
                              cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        url = None
        assert server.stdout is not None
        for line in server.stdout:  # it prints the URL once the page answers
            if f"http://localhost:{port}/?url=" in line:
                url = line.strip()
                break
        assert url is not None, server.stderr.read() if server.stderr else ""
        assert f"ssh -L {port}:localhost:{port} -L {port + 1}:localhost:{port + 1}" in server.stdout.readline()

        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            page = browser.new_page(viewport=VIEWPORT)
            page.goto(url)
            # Chromium's own capture: Playwright's waits for a quiet page, which a viewer drawing
            # every frame in software may not give it in time.
            cdp = page.context.new_cdp_session(page)
            # NDFA_VIEWER_SCREENSHOT=docs/viewer_blueprint.png: wait for the whole run instead, keep the last.
            keep = os.environ.get("NDFA_VIEWER_SCREENSHOT")
            wait_s = SCREENSHOT_LOAD_S if keep else LOAD_S
            deadline, shot = time.monotonic() + wait_s, np.zeros((1, 1, 3), np.uint8)
            while time.monotonic() < deadline:
                time.sleep(5)
                png = tmp_path / "viewer.png"
                png.write_bytes(base64.b64decode(cdp.send("Page.captureScreenshot", {"format": "png"})["data"]))
                shot = np.asarray(Image.open(png).convert("RGB"))
                print(f"{wait_s - deadline + time.monotonic():.0f} s: (coloured pixels, cells) {scene_pixels(shot)}")
                if drew_the_scene(shot) and not keep:
                    break
            browser.close()
        count, cells = scene_pixels(shot)
        assert drew_the_scene(shot), f"the world view stayed empty for {wait_s} s: {count} coloured pixels in {cells} cells"
        if keep:
            shutil.copy(png, keep)
    finally:
        server.send_signal(signal.SIGINT)  # ndfa stops Rerun's server, then exits
        try:
            server.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
