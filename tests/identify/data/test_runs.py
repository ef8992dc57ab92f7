import numpy as np
import pytest

from identify import Run, RunError, read_run, read_runs

from tests.helpers import one_error_line, run_cli

HEAD = "# aircraft: S 61\n# pilot: test\ntime,theta_s,q\n"


def write(tmp_path, body, head=HEAD, name="run.csv"):
    path = tmp_path / name
    path.write_text(head + body)
    return path


def test_round_trip_keeps_data_and_metadata(tmp_path, rng):
    t = np.arange(200) * 0.011
    run = Run(t, {"theta_s": rng.standard_normal(200), "q": rng.standard_normal(200)},
              {"aircraft": "BO 105", "note": "two\nlines"})
    back = read_run(run.to_csv(tmp_path / "r.csv"), require=["q"])
    np.testing.assert_allclose(back.time, t, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back["q"], run["q"], rtol=1e-14)
    assert back.meta["aircraft"] == "BO 105" and back.meta["note"] == "two lines"
    assert back.dt == pytest.approx(0.011)


@pytest.mark.parametrize("body, needle", [
    ("0,0,0\n0.01,0,nan\n0.02,0,0\n", "line 5, channel 'q': nan"),
    ("0,0,0\n0.01,0,inf\n0.02,0,0\n", "line 5, channel 'q': inf"),
    ("0,0,0\n0.01,abc,0\n0.02,0,0\n", "line 5, channel 'theta_s': not a number ('abc')"),
    ("0,0,0\n0.01,0\n0.02,0,0\n", "line 5: 2 values for 3 columns"),
    ("0,0,0\n0.01,0,0\n0.01,0,0\n0.02,0,0\n", "line 6, channel 'time': repeated time stamp"),
    ("0,0,0\n0.02,0,0\n0.01,0,0\n", "line 6, channel 'time': decreasing time stamp"),
    ("0,0,0\n0.01,0,0\n0.03,0,0\n0.04,0,0\n", "time gap(s) longer than 1.5 x the 0.01 s step at line 6"),
    ("0,0,0\n0.01,0,0\n0.0212,0,0\n0.03,0,0\n0.04,0,0\n", "line 6, channel 'time'"),
    ("0,0,0\n", "fewer than two data rows"),
])
def test_bad_rows_give_file_line_and_channel(tmp_path, body, needle):
    path = write(tmp_path, body)
    with pytest.raises(RunError) as err:
        read_run(path)
    assert str(err.value).startswith(str(path)) and needle in str(err.value), str(err.value)
    assert "\n" not in str(err.value)


def test_irregular_sampling_is_named(tmp_path):
    with pytest.raises(RunError, match=r"12% of a step off the uniform 0.01 s grid \(irregular sampling"):
        read_run(write(tmp_path, "0,0,0\n0.01,0,0\n0.0212,0,0\n0.03,0,0\n0.04,0,0\n"))


def test_missing_channels_are_all_listed(tmp_path):
    path = write(tmp_path, "0,0,0\n0.01,0,0\n")
    with pytest.raises(RunError, match=r"missing channel\(s\) p, phi needed"):
        read_run(path, require=["q", "p", "phi"])


def test_header_problems(tmp_path):
    with pytest.raises(RunError, match="no 'time' column"):
        read_run(write(tmp_path, "0,0\n1,1\n", head="a,b\n"))
    with pytest.raises(RunError, match="duplicate column"):
        read_run(write(tmp_path, "0,0,0\n1,1,1\n", head="time,q,q\n"))
    with pytest.raises(RunError, match="no header"):
        read_run(write(tmp_path, "", head="# only: comments\n"))


def test_unreadable_files(tmp_path):
    with pytest.raises(RunError, match="cannot read"):
        read_run(tmp_path / "missing.csv")
    binary = tmp_path / "b.csv"
    binary.write_bytes(b"\xff\xfe\x00\x01" * 10)
    with pytest.raises(RunError, match="not a text"):
        read_run(binary)


def test_multi_run_read_and_slice(tmp_path):
    a = write(tmp_path, "0,0,0\n0.5,1,1\n1.0,0,2\n", name="a.csv")
    b = write(tmp_path, "0,0,0\n0.5,1,1\n", name="b.csv")
    runs = read_runs([a, b], require=["q"])
    assert [len(r) for r in runs] == [3, 2]
    s = runs[0].slice(0.4, 1.0)
    np.testing.assert_array_equal(s["q"], [1, 2])
    with pytest.raises(RunError):
        runs[0].slice(5, 6)
