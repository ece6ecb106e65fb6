"""`m4-sitl fly --video`: a short flight on film, rendered offscreen by MuJoCo after the flight."""

from __future__ import annotations

import imageio_ffmpeg
import pytest
from PIL import Image

from sitl.cli import main
from sitl.flights.video import SNAPSHOT_OFFSETS_S

pytestmark = pytest.mark.flight

SCENARIO = """name = "short-hover"
duration_s = 0.5

[start]
ned_m = [0.0, 0.0, -2.0]

[[fault]]
at_s = 0.2
rotor = 2
loss = 1.0
"""


def test_a_short_flight_with_video_makes_an_h264_mp4_at_real_time_and_the_snapshots(tmp_path, capsys):
    scenario = tmp_path / "short.toml"
    scenario.write_text(SCENARIO)
    out = tmp_path / "flight"
    assert main(["fly", str(scenario), "--out", str(out), "--video", "--video-size", "160x96"]) == 0
    assert f"video: {out / 'flight.mp4'}, {out / 'snapshots_render.png'}" in capsys.readouterr().out

    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(out / "flight.mp4"))
    assert frames == 16                                  # 0 to 0.5 s of simulated time at 30 fps
    assert seconds == pytest.approx(0.5, abs=0.04)       # real time
    reader = imageio_ffmpeg.read_frames(str(out / "flight.mp4"))
    meta = next(reader)
    assert meta["size"] == (160, 96) and meta["codec"].startswith("h264")
    first = next(reader)
    assert len(first) == 160 * 96 * 3 and len(set(first)) > 20     # a picture, not a blank frame
    reader.close()

    sheet = Image.open(out / "snapshots_render.png")
    assert sheet.size == (4 * 80, 2 * (96 // 2 * 3 // 2)) and len(SNAPSHOT_OFFSETS_S) == 8
