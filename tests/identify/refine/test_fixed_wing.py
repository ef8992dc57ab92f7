"""A refined model is a model (issue 10): a stable fixed-wing longitudinal truth with turbulence, an
elevator delay and a pitch-attitude sensor drift the declared model lacks. refine finds both; its
``final_profile.toml`` is then used, as is, by ``identify estimate`` and ``identify refine`` on new
plain measured runs (CSV files holding only the recorded channels: the delayed elevator and the
drift's time channel are rebuilt from the profile)."""
import json

import numpy as np

from identify import LinearModel, load_profile, parse_profile, simulate_run
from identify.cli import main
from identify.refine import Refine

# a light aircraft at 50 m/s, body axes, SI units; theta_dot = q and the gravity and Z_q = U0 terms
# are kinematics (fixed), the aerodynamic derivatives free
FIXED_WING = """
name = "fixed wing, longitudinal (test)"
states = { u = "m/s", w = "m/s", q = "rad/s", theta = "rad" }
inputs = { de = "rad" }
outputs = ["u", "w", "q", "theta"]
[free]
X_u = -0.045
X_w = 0.036
Z_u = -0.37
Z_w = -2.0
Z_de = -10.0
M_w = -0.05
M_q = -2.0
M_de = -8.0
[fixed]
X_theta = -9.81
Z_q = 50.0
theta_q = 1.0
"""
DT, N = 0.02, 1001
TAU, DRIFT = 0.06, 0.001  # s elevator delay; rad/s drift of the attitude sensor
TURBULENCE = np.array([0.05, 0.2, 0.05, 0.0])  # per-sample std on the X, Z, M equations


def _runs(seeds):
    model = LinearModel(parse_profile(FIXED_WING))
    t = np.arange(N) * DT
    runs = []
    for s in seeds:
        rng = np.random.default_rng(s)
        de = np.repeat(rng.choice([-1.0, 0.0, 1.0], size=N // 25 + 1), 25)[:N] * 0.02
        de[:25] = 0.0
        late = np.concatenate([np.zeros(3), de[:-3]])  # 3 samples = TAU
        run = simulate_run(model, t, late[:, None], noise_fraction=0.01, process_noise=TURBULENCE, seed=s)
        runs.append(run.with_channels({"de": de, "theta": run["theta"] + DRIFT * t}))
    return runs


def test_fixed_wing_refined_model_reused_by_estimate_and_refine(tmp_path, capsys):
    declared = parse_profile(FIXED_WING)
    assert all(m.stable for m in LinearModel(declared).modes())
    fit = _runs((1, 2, 3))
    r = Refine(declared, kinds=("derivative", "delay", "lag", "drift"), max_steps=2).fit(fit[:2], validate=fit[2:])
    found = {(s.effect, s.target): s for s in r.steps_}
    assert ("drift", "theta") in found, [s.to_dict() for s in r.steps_ + r.rejected_]
    assert {("delay", "de"), ("lag", "de")} & set(found), [s.to_dict() for s in r.steps_ + r.rejected_]
    if ("delay", "de") in found:
        tau = found[("delay", "de")].parameters["tau_de"]
        assert abs(tau["value"] - TAU) < 4 * tau["std"] + 0.005, tau
    final = r.profile_.save(tmp_path / "final_profile.toml")
    assert load_profile(final).meta["pseudo_inputs"]["t"] == {"time": 1}

    # new flights, recorded channels only
    new = _runs((21, 22, 23))
    files = [run.to_csv(tmp_path / f"new{i}.csv", ["de", "u", "w", "q", "theta"]) for i, run in enumerate(new)]
    capsys.readouterr()
    assert main(["estimate", "--method", "ml", "--profile", str(final), str(files[0]), str(files[1]), "--out",
                 str(tmp_path / "est")]) == 0, capsys.readouterr().err
    result = json.loads((tmp_path / "est" / "result.json").read_text())
    est = {p["name"]: p for p in result["parameters"]} if isinstance(result["parameters"], list) \
        else result["parameters"]
    drift = est["drift_theta"]
    assert abs(drift["value"] - DRIFT) < 0.2 * DRIFT, drift
    assert main(["refine", "--profile", str(final), str(files[0]), str(files[1]), "--validate", str(files[2]),
                 "--kinds", "delay,lag,drift", "--max-steps", "1", "--out", str(tmp_path / "ref")]) == 0
    again = json.loads((tmp_path / "ref" / "refine.json").read_text())
    # nothing left to find: the effects are in the model, and it predicts the new flights as well
    # as the flights it was refined on (turbulence sets the floor)
    assert again["steps"] == [], again["steps"]
    assert again["error_before"]["validation"]["overall"] < 1.3 * r.error_after_["validation"]["overall"]
    assert again["error_before"]["validation"]["overall"] < 0.7 * r.error_before_["validation"]["overall"]
