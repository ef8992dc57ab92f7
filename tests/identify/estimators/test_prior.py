"""A priori weighting in the estimators: posterior, data share, conflict tests, result.json."""
from dataclasses import replace

import numpy as np
import pytest

from identify import LS, ML, LinearModel, load_profile, simulate_run
from identify.estimators.prior import PriorTerm, combine, posterior


@pytest.fixture(scope="module")
def hover():
    """The S 61 4-DOF hover model, one 7 s 3211 per cyclic, 3 % noise."""
    prof = load_profile("s61_hover_4dof")
    truth = LinearModel(prof)
    t = np.arange(0, 7, 0.05)
    runs = []
    for k in range(2):
        u = np.zeros((len(t), 2))
        u[(t > 0.5) & (t < 2.6), k] = np.deg2rad(0.5)  # a 2 s pulse then the return
        u[(t >= 2.6) & (t < 3.3), k] = -np.deg2rad(0.5)
        runs.append(simulate_run(truth, t, u, noise_fraction=0.03, seed=40 + k))
    return prof, runs


def _with_prior(prof, prior):
    return replace(prof, prior=prior)


def test_conflict_covariance_is_prior_minus_posterior_for_white_residuals():
    rng = np.random.default_rng(1)
    G = rng.standard_normal((6, 3))
    M = G.T @ G  # data information
    term = PriorTerm(["a", "b", "c"], np.zeros(3), np.array([0.5, 2.0, np.inf]))
    theta, A, D = combine(term, np.array([0.3, -0.2, 0.1]), np.linalg.inv(M), info_d=M)
    cov, rec = posterior(term, theta, A, D)
    np.testing.assert_allclose(cov, A, atol=1e-12)  # white: posterior covariance (M + P^-1)^-1
    V = np.diag(term.std[:2] ** 2) - A[:2, :2]  # Cov(posterior - prior) under an honest prior
    for j, n in enumerate("ab"):
        assert rec["parameters"][n]["conflict_z"] == pytest.approx(theta[j] / np.sqrt(V[j, j]))
        assert rec["parameters"][n]["data_share"] == pytest.approx(1 - A[j, j] / term.std[j] ** 2)
    assert rec["without_prior"] == ["c"]


def test_conflict_z_is_standard_normal_under_an_honest_prior():
    """Monte Carlo over prior draws and data noise: the z of each parameter has unit spread
    (judging by the prior's std alone would make it far smaller where the data dominate)."""
    rng = np.random.default_rng(2)
    G = rng.standard_normal((8, 3)) * np.array([10.0, 1.0, 0.1])  # data shares ~1, ~0.5, ~0
    M, std = G.T @ G, np.ones(3)
    z = []
    for _ in range(400):
        truth = rng.standard_normal(3)
        mu = truth + std * rng.standard_normal(3)
        data = truth + np.linalg.cholesky(np.linalg.inv(M)) @ rng.standard_normal(3)
        term = PriorTerm(list("abc"), mu, std)
        theta, A, D = combine(term, data, np.linalg.inv(M), info_d=M)
        rec = posterior(term, theta, A, D)[1]
        z.append([rec["parameters"][n]["conflict_z"] for n in "ab"])
    assert np.std(np.array(z, float), axis=0) == pytest.approx([1.0, 1.0], abs=0.12)


def test_ml_posterior_share_and_result_json(hover):
    prof, runs = hover
    data = ML(prof).fit(runs).result_
    rel = data.std / np.abs(data.theta)
    poor, good = int(np.argmax(rel)), int(np.argmin(rel))
    names = data.names
    prior = {n: {"value": v, "std": 0.2 * abs(v)} for n, v in prof.free.items()}
    post = ML(_with_prior(prof, prior)).fit(runs).result_
    rec = post.info["prior"]
    assert rec["parameters"][names[poor]]["data_share"] < rec["parameters"][names[good]]["data_share"]
    assert post.std[poor] < 0.8 * data.std[poor]  # the prior adds information where the data lack it
    assert abs(post.theta[good] - data.theta[good]) < 0.5 * data.std[good]
    assert not rec["conflict"]["detected"]
    out = post.to_dict()["parameters"][names[poor]]
    assert out["prior"] == prior[names[poor]] and 0 <= out["data_share"] <= 1
    assert "a priori weighting" in post.summary()


def test_ml_conflict_names_the_wrong_derivative(hover):
    prof, runs = hover
    prior = {n: {"value": v, "std": 0.2 * abs(v)} for n, v in prof.free.items()}
    prior["M_q"]["value"] = prof.free["M_q"] * 1.6  # 3 prior stds off on a well-identified derivative
    rec = ML(_with_prior(prof, prior)).fit(runs).result_.info["prior"]
    assert rec["conflict"]["detected"] and rec["conflict"]["drivers"][0] == "M_q"
    assert "PRIOR-DATA CONFLICT" in ML(_with_prior(prof, prior)).fit(runs).result_.summary()


def test_ls_mixed_estimation_between_data_and_prior(hover):
    prof, runs = hover
    data = LS(prof).fit(runs).result_
    j = data.names.index("Y_theta_s")
    centre = data.theta[j] + 5 * data.std[j]
    est = {}
    for std in (1e3 * data.std[j], data.std[j], 1e-3 * data.std[j]):
        fit = LS(_with_prior(prof, {"Y_theta_s": {"value": centre, "std": std}})).fit(runs).result_
        est[std] = fit.theta[j]
    wide, equal, tight = est.values()
    assert wide == pytest.approx(data.theta[j], abs=0.01 * data.std[j])
    assert tight == pytest.approx(centre, abs=0.01 * data.std[j])
    assert data.theta[j] < equal < centre


def test_refine_candidates_carry_the_prior_and_added_effects_have_none(hover):
    from identify.estimators.prior import prior_term
    from identify.refine.candidates import _add

    prof, _ = hover
    p = _with_prior(prof, {"M_q": {"value": -0.5, "std": 0.05}})
    extended = _add(p, free={"M_v": 0.0})
    term = prior_term(extended)
    assert extended.prior == p.prior
    assert term.has[term.names.index("M_q")] and not term.has[term.names.index("M_v")]
