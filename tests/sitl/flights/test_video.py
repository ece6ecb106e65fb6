"""The flight video's pieces without a flight: frame instants, captions, errors."""

from __future__ import annotations

import numpy as np
import pytest

from sitl.plant.truth import TruthRecorder
from sitl.flights.video import VideoError, captions, frame_times_s, make_video, snapshot_times_s

METRICS = {"scenario": "hover-rotor-loss", "controller": "nmpc",
           "faults": [{"at_s": 1.0, "rotor": 4, "loss": 1.0, "detected_at_s": 1.04, "detected_rotor": 4}]}


def _truth(t1_s: float):
    class Times:                      # only time_s is read by the functions under test
        time_s = np.arange(0.0, t1_s + 1e-9, 0.01)
    return Times()


def test_frames_are_one_per_fps_period_of_simulated_time_from_the_first_sample_to_the_last():
    times = frame_times_s(_truth(8.0), 30.0)
    assert len(times) == 241 and times[0] == 0.0 and times[-1] == pytest.approx(8.0)
    assert np.allclose(np.diff(times), 1 / 30)
    assert len(frame_times_s(_truth(0.5), 30.0)) == 16


def test_captions_add_the_fault_at_its_instant_and_the_detection_at_its_own():
    assert [text for text, _ in captions(METRICS, 0.99)] == ["hover-rotor-loss (nmpc)   t =  0.99 s"]
    assert [text for text, _ in captions(METRICS, 1.02)][1:] == ["rotor 4 lost 100% of its thrust at 1 s"]
    assert [text for text, _ in captions(METRICS, 1.05)][2:] == ["detected rotor 4 after 0.04 s"]


def test_snapshots_gather_around_the_first_fault_and_stay_inside_the_flight():
    times = snapshot_times_s(_truth(2.5), METRICS)
    assert times[0] == pytest.approx(0.5) and times[1] == pytest.approx(1.0) and times[-1] == pytest.approx(2.5)
    assert snapshot_times_s(_truth(7.0), {})[-1] == pytest.approx(7.0)


def test_a_folder_without_truth_is_refused_in_one_line(tmp_path):
    with pytest.raises(VideoError, match="no truth.npz"):
        make_video(tmp_path)


def test_an_unusable_gl_back_end_is_named(tmp_path, monkeypatch):
    TruthRecorder().save(tmp_path / "truth.npz")
    monkeypatch.setenv("MUJOCO_GL", "no-such-gl")
    with pytest.raises(VideoError, match="no-such-gl: .*MUJOCO_GL") as error:
        make_video(tmp_path)
    assert "\n" not in str(error.value)
