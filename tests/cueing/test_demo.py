"""The demo pipeline (design -> fly -> identify -> refine -> report) at reduced size."""
import re

from cueing.demo import DELAY, run_demo


def test_demo_pipeline_finds_the_undeclared_delay(tmp_path):
    report = run_demo(tmp_path / "demo", quick=True, say=lambda *_: None)
    text = report.read_text()
    out = report.parent
    for name in ("signals.json", "signals.png", "display.png", "flown_vs_designed.png", "time_history_ml.png",
                 "residuals_ml.png", "testpoint_1.csv", "testpoint_2.csv", "refine/refine.json",
                 "refine/final_profile.toml"):
        assert (out / name).exists(), name
    for link in re.findall(r"!\[[^]]*\]\(([^)]+)\)", text):  # every figure the report shows exists
        assert (out / link).exists(), link
    # the default design, its peak responses against the limits, one of them binding
    assert "Peak response on the a priori model against the limits" in text and "(binds)" in text
    # the refine step names the undeclared effect: the truth's delay on each cyclic, within 3 std
    found = re.findall(r"\*\*delay\*\* on `(theta_[sc])`: `tau_theta_[sc]` = ([0-9.]+) ± ([0-9.e-]+)", text)
    assert sorted(f[0] for f in found) == ["theta_c", "theta_s"], text
    assert all(abs(float(v) - DELAY) < 3 * float(s) for _, v, s in found), found
    before, after = map(float, re.search(r"\| validation runs \| ([0-9.]+) \| ([0-9.]+) \|", text).groups())
    assert after < before
