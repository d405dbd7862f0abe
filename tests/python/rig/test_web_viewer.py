"""The recording in a real browser: `rig view --web`'s server, headless Chromium (Debian's
package, software GL), the blueprint drawn, a screenshot that is not blank, no viewer error.
And a live run streamed to the web viewer (`rig run --live --web`).

Skipped only where chromium is not installed (./hil install installs it as root)."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from rig import cli
from rig.results import browser, recording, webview

pytestmark = pytest.mark.skipif(
    browser.chromium_path() is None,
    reason="chromium is not installed (Debian: apt-get install chromium; ./hil install as root)")


@pytest.fixture
def viewer_env(tmp_path: Path) -> dict[str, str]:
    """A fresh HOME for the Rerun server: its first session sends no usage data."""
    home = tmp_path / "home"
    home.mkdir()
    return {"HOME": str(home), "XDG_CONFIG_HOME": str(home / ".config"),
            "XDG_DATA_HOME": str(home / ".local" / "share")}


@pytest.fixture
def served(hil_run, tmp_path: Path,  # type: ignore[no-untyped-def]
           viewer_env: dict[str, str]) -> Iterator[tuple[webview.WebViewer, Path]]:
    run = hil_run("smoke", bus="inproc", keep="failing")  # what a passing run keeps
    assert run.passed, run.explain()
    rrd = run.out_dir / "recording.rrd"
    with webview.start([rrd], web_port=webview.free_port(), grpc_port=webview.free_port(),
                       log=tmp_path / "rerun.log", env=viewer_env) as viewer:
        yield viewer, run.out_dir


def _colour_pixels(png: Path, rgb: list[int], tol: int = 40) -> int:
    img = np.asarray(Image.open(png).convert("RGB"), dtype=np.int16)
    return int(np.count_nonzero(np.all(np.abs(img - np.asarray(rgb)) <= tol, axis=2)))


def _assert_not_blank(png: Path, size: tuple[int, int] = (1600, 1000)) -> None:
    img = Image.open(png).convert("RGB")
    assert img.size == size
    pixels = np.asarray(img, dtype=np.float64)
    assert pixels.std() > 10.0  # not one flat colour
    assert len(img.getcolors(maxcolors=1 << 20) or []) > 200  # text, lines, panels


def test_a_recording_opens_in_chromium(served: tuple[webview.WebViewer, Path],
                                       tmp_path: Path) -> None:
    viewer, run_dir = served
    png = tmp_path / "viewer.png"
    seen = browser.look(viewer.url(renderer="webgl"), png,
                        expect=[f"hil-{run_dir.name}", *recording.VIEW_NAMES])
    assert seen.ok, f"the viewer reported: {seen.panic or seen.errors}"
    assert f"hil-{run_dir.name}" in seen.state_text  # our recording is the one shown
    _assert_not_blank(png)
    # the time series are drawn: θ (true) and the position error in the palette's first
    # colour, θ̂ in its second
    assert _colour_pixels(png, recording.PALETTE[0]) > 500
    assert _colour_pixels(png, recording.PALETTE[1]) > 200
    if os.environ.get("HIL_SCREENSHOT_DIR"):  # keep it (CI artefacts, the README's picture)
        Path(os.environ["HIL_SCREENSHOT_DIR"]).mkdir(parents=True, exist_ok=True)
        png.replace(Path(os.environ["HIL_SCREENSHOT_DIR"]) / "web-viewer.png")


def test_a_live_run_streams_to_the_web_viewer(hil_run, tmp_path: Path,  # type: ignore[no-untyped-def]
                                              viewer_env: dict[str, str]) -> None:
    with webview.start(web_port=webview.free_port(), grpc_port=webview.free_port(),
                       log=tmp_path / "rerun.log", env=viewer_env) as viewer:
        run = hil_run("smoke", live=True, live_url=viewer.grpc_url, keep="failing")
        assert run.passed, run.explain()
        assert run.bus != "inproc"  # the live view needs the bus's telemetry
        # the server keeps what was streamed: the live blueprint and its data open later
        png = tmp_path / "live.png"
        seen = browser.look(viewer.url(renderer="webgl"), png,
                            expect=["sensorless_hil_live", "θ est and θ (deg)", "speed (r/min)"],
                            width=1024, height=640)  # a live view repaints: a smaller page
    assert seen.ok, f"the viewer reported: {seen.panic or seen.errors}"
    _assert_not_blank(png, (1024, 640))


def test_view_usage_and_a_taken_port(tmp_path: Path, served: tuple[webview.WebViewer, Path],
                                     capsys: pytest.CaptureFixture[str]) -> None:
    viewer, run_dir = served
    assert cli.main(["view", str(run_dir), "--screenshot", str(tmp_path / "x.png")]) == 2
    assert "--screenshot needs --web" in capsys.readouterr().err
    assert cli.main(["view", str(run_dir), "--web", "--web-port", str(viewer.web_port),
                     "--grpc-port", str(webview.free_port())]) == 3
    assert "already in use" in capsys.readouterr().err
    assert cli.main(["run", "smoke", "--web", "--out", str(tmp_path / "o")]) == 2
    data = json.loads((run_dir / "result.json").read_text())
    assert data["kept"]["full_rate"] is False  # served from what a passing run keeps
