"""The report's SVG chart kit: round tick values, decimation that keeps a line's shape, and the
video encoder's sizing of frames that arrive one at a time."""
from __future__ import annotations

import numpy as np
import pytest

from recording.report.data import CameraFrame
from recording.report.svg_chart import Panel, decimate, log_ticks, nice_ticks, tick_label
from recording.report.video import MIN_HEIGHT, VideoEncoder


def test_ticks_are_round_values_inside_the_range():
    assert nice_ticks(0.0, 31.0, 8) == [0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0]
    assert nice_ticks(-1.93, -1.37, 4) == pytest.approx([-1.8, -1.6, -1.4])
    assert nice_ticks(-0.8, 0.6, 4) == pytest.approx([-0.5, 0.0, 0.5])
    assert nice_ticks(1.0, 1.0, 4) == [] and nice_ticks(0.0, float("nan"), 4) == []
    assert log_ticks(0.002, 15.0) == pytest.approx([0.01, 0.1, 1.0, 10.0])
    assert [tick_label(t, 0.25) for t in (0.0, 0.25, 0.5)] == ["0.00", "0.25", "0.50"]
    assert tick_label(-1.6, 0.2) == "-1.6" and tick_label(20.0, 5.0) == "20"


def test_decimation_keeps_extremes_and_order_and_drops_nan():
    times = np.linspace(0.0, 31.0, 1550)
    values = np.sin(times)
    values[700] = 5.0  # a one-sample spike must survive
    values[10] = np.nan
    t, v = decimate(times, values, 100)
    assert len(t) <= 400 and np.all(np.diff(t) > 0)
    assert v.max() == 5.0 and v.min() == pytest.approx(values[np.isfinite(values)].min())
    assert not np.isnan(v).any()
    short_t, short_v = decimate(times[:50], values[:50], 100)  # few points: all kept (but the NaN)
    assert len(short_t) == 49


def test_panel_maps_data_to_pixels_with_the_y_axis_pointing_up():
    panel = Panel("p", 10, 20, 100, 50, (0.0, 10.0), (-1.0, 1.0))
    assert panel.px(0.0) == 10 and panel.px(10.0) == 110
    assert panel.py(-1.0) == 70 and panel.py(1.0) == 20
    log = Panel("l", 0, 0, 100, 30, (0.0, 1.0), (0.001, 1.0), log_y=True)
    assert log.py(0.01) == pytest.approx(20.0)


def frame(views: list[tuple[int, int]]) -> CameraFrame:
    return CameraFrame(0.0, 1, [(f"v{k}", np.full((h, w, 3), 100 + k, np.uint8)) for k, (h, w) in enumerate(views)])


def test_video_size_is_set_by_the_first_frame_and_later_frames_fit_it(tmp_path):
    import imageio.v2 as imageio

    encoder = VideoEncoder(tmp_path / "v.mp4")
    encoder.add(frame([(32, 32), (32, 32)]))
    encoder.add(frame([(32, 32)]))  # fewer views: padded
    encoder.add(frame([(32, 32), (32, 32), (32, 32)]))  # more views: scaled down to fit
    encoder.close_soon()  # as the worker does when the run ends
    assert encoder.close() == tmp_path / "v.mp4" and sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]
    reader = imageio.get_reader(tmp_path / "v.mp4")
    try:
        shapes = [f.shape for f in reader]
    finally:
        reader.close()
    assert shapes == [(MIN_HEIGHT, 2 * MIN_HEIGHT, 3)] * 3


def test_a_video_without_frames_says_so_and_a_discarded_one_leaves_no_file(tmp_path):
    with pytest.raises(ValueError, match="no camera frames were recorded"):
        VideoEncoder(tmp_path / "none.mp4").close()
    encoder = VideoEncoder(tmp_path / "gone.mp4")
    encoder.add(frame([(32, 32)]))
    assert not (tmp_path / "gone.mp4").exists()  # never a half-written video under its name
    encoder.discard()
    assert list(tmp_path.iterdir()) == []
