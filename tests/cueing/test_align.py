"""cueing align: the clock offset between the display's log and a separate recording."""
import numpy as np
import pytest

from cueing.align import find_offset, merge
from cueing.errors import CueingError
from identify import Run


def _stick(t):
    rng = np.random.default_rng(3)
    switches = np.cumsum(rng.uniform(0.3, 1.2, 40))
    levels = rng.choice([-1.0, 0.0, 1.0], switches.size)
    return np.where(t[:, None] >= switches[None, :], 1.0, 0.0).dot(np.diff(np.r_[0.0, levels]))


@pytest.mark.parametrize("offset", [3.7413, -1.234])
def test_offset_found_between_samples_on_other_rates(offset):
    t_disp = np.arange(0, 15, 1 / 60)
    display = Run(t_disp, {"theta_s": 0.02 * _stick(t_disp), "theta_s_cmd": 0.02 * _stick(t_disp)}, source="disp")
    t_rec = np.arange(0, 25, 0.02) - 5.0
    noise = np.random.default_rng(1).normal(0, 1e-3, t_rec.size)
    recording = Run(t_rec, {"theta_s": 0.02 * _stick(t_rec - offset) + noise, "q": np.sin(t_rec)}, source="rec")
    found = find_offset(display, recording, "theta_s")
    assert abs(found.offset - offset) < 0.25 * 0.02 and found.correlation > 0.95
    merged = merge(display, recording, found)
    assert {"theta_s", "theta_s_display", "theta_s_cmd", "q"} <= set(merged.channels)
    assert merged.time[0] >= -1e-9 and merged.time[-1] <= t_disp[-1] + 1e-9
    # noise (1e-3) and steps falling between samples remain; a wrong offset leaves about 1.4 std
    assert np.std(merged["theta_s"] - merged["theta_s_display"]) < 0.25 * np.std(merged["theta_s"])


def test_unshared_or_still_channel_is_an_error():
    t = np.arange(0, 5, 0.02)
    a, b = Run(t, {"theta_s": np.sin(t)}, source="a"), Run(t, {"theta_c": np.sin(t), "theta_s": 0 * t}, source="b")
    with pytest.raises(CueingError, match="no channel 'theta_c'"):
        find_offset(a, b, "theta_c")
    with pytest.raises(CueingError, match="does not move in b"):
        find_offset(a, b, "theta_s")
