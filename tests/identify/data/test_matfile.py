import json

import numpy as np
import pytest
from scipy.io import savemat

from identify import RunError, read_mat
from identify.data.io import load_channel_map, read_run_file

DT = 0.011


@pytest.fixture
def signals():
    t = np.arange(200) * DT
    return {"t": t, "q": np.sin(t), "theta": np.cos(t) * 0.1, "de": np.sign(np.sin(3 * t))}


def test_named_variables_with_channel_map(tmp_path, signals):
    path = tmp_path / "run.mat"
    # MATLAB stores vectors as columns or rows: both must read
    savemat(path, {"t": signals["t"][:, None], "q_meas": signals["q"], "th": signals["theta"][None, :],
                   "elev": signals["de"]})
    run = read_mat(path, {"q": "q_meas", "theta": "th", "theta_s": "elev"})
    assert set(run.channels) == {"q", "theta", "theta_s"}
    np.testing.assert_array_equal(run.time, signals["t"])
    np.testing.assert_array_equal(run["q"], signals["q"])
    np.testing.assert_array_equal(run["theta"], signals["theta"])
    assert run.dt == pytest.approx(DT)
    assert json.loads(run.meta["channel_map"])["q"] == "q_meas"


def test_without_map_every_vector_of_the_right_length_is_a_channel(tmp_path, signals):
    path = tmp_path / "run.mat"
    savemat(path, {**signals, "note": "flight 12", "short": np.ones(5)})
    run = read_mat(path)
    assert set(run.channels) == {"q", "theta", "de"}


def test_data_matrix_with_column_map_and_time_column(tmp_path, signals):
    Z = np.column_stack([signals["t"], signals["q"], signals["theta"], signals["de"]])
    path = tmp_path / "sidpac.mat"
    savemat(path, {"Z": Z})
    run = read_mat(path, {"q": 1, "theta": 2, "theta_s": 3}, time=0)
    np.testing.assert_array_equal(run["theta"], signals["theta"])
    np.testing.assert_array_equal(run.time, signals["t"])
    # no time column: a sample interval instead; another matrix name
    path2 = tmp_path / "fvsysid.mat"
    savemat(path2, {"data": Z[:, 1:]})
    run2 = read_mat(path2, {"q": 0, "theta_s": 2}, dt=DT)
    np.testing.assert_allclose(run2.time, signals["t"], atol=1e-12)
    np.testing.assert_array_equal(run2["theta_s"], signals["de"])


def test_channel_map_json_and_dispatch_by_suffix(tmp_path, signals):
    Z = np.column_stack([signals["q"], signals["theta"]])
    savemat(tmp_path / "m.mat", {"fdata": Z})
    spec = tmp_path / "map.json"
    spec.write_text(json.dumps({"channels": {"q": 0, "theta": 1}, "matrix": "fdata", "dt": DT}))
    run = read_run_file(tmp_path / "m.mat", load_channel_map(spec))
    np.testing.assert_array_equal(run["q"], signals["q"])
    flat = load_channel_map('{"q": "q_meas"}')
    assert flat == {"channels": {"q": "q_meas"}}
    with pytest.raises(RunError, match="not valid JSON"):
        load_channel_map("{q: 1}")
    with pytest.raises(RunError, match="unknown key"):
        load_channel_map('{"channels": {"q": 0}, "colour": 1}')


@pytest.mark.parametrize("case, needles", [
    ("missing variable", ["bad.mat", "no variable 'r_meas'", "channel 'r'"]),
    ("wrong length", ["bad.mat", "channel 'theta'", "199 samples", "time has 200"]),
    ("nan", ["bad.mat", "sample 17, channel 'q': nan value"]),
    ("column out of range", ["bad.mat", "column 7 out of range"]),
    ("no time", ["bad.mat", "no time variable"]),
    ("not a mat file", ["bad.mat", "not a readable MATLAB"]),
    ("no file", ["bad.mat", "no such file"]),
])
def test_bad_files_give_one_clear_line(tmp_path, signals, case, needles):
    path = tmp_path / "bad.mat"
    s = dict(signals)
    channels, kwargs = {"q": "q", "theta": "theta"}, {}
    if case == "missing variable":
        channels["r"] = "r_meas"
    elif case == "wrong length":
        s["theta"] = s["theta"][:-1]
    elif case == "nan":
        s["q"] = s["q"].copy()
        s["q"][16] = np.nan
    elif case == "column out of range":
        s = {"data": np.column_stack([s["t"], s["q"]])}
        channels, kwargs = {"q": 7}, {"time": 0}
    elif case == "no time":
        del s["t"]
    if case == "not a mat file":
        path.write_text("time,q\n0,1\n")
    elif case != "no file":
        savemat(path, s)
    with pytest.raises(RunError) as err:
        read_mat(path, channels, **kwargs)
    msg = str(err.value)
    assert "\n" not in msg
    for needle in needles:
        assert needle in msg, (needle, msg)
