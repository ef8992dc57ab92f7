"""Sets of models around the a priori: what a design must stay good on when the a priori is wrong.

Two kinds of a priori error matter for input design (Kaletka & Rix section 4: a wide band makes
"errors in the a priori model matter little"):

* every derivative off by a factor (0.7..1.3 by default, :func:`~signaldesign.evaluate.perturbed_models`);
* the dynamics faster or slower than predicted. :func:`frequency_scaled` multiplies A and B by k,
  which multiplies every eigenvalue by k and keeps the static gains -C A^-1 B: the same aircraft on
  a time axis stretched by 1/k. A narrow-band input tuned on the a priori then excites the wrong
  frequencies, the error that costs a 3211 most.
"""
from __future__ import annotations

import numpy as np

from identify import LinearModel

from .evaluate import PERTURBATION, DesignError

FREQUENCY_RANGE = (0.6, 1.6)  # the issue's "dominant modes' frequencies scaled by about 0.6..1.6"


def frequency_scaled(model: LinearModel, k: float) -> LinearModel:
    """The model with A and B multiplied by ``k`` (every eigenvalue times k): every parameter that
    acts on A or B, free or fixed, is scaled; output-equation parameters (C, D) are not."""
    if not (np.isfinite(k) and k > 0):
        raise DesignError(f"frequency scale must be positive, got {k:g}")
    p = model.profile
    values = dict(zip(model.names, model.theta))
    scaled = {}
    for name in list(p.free) + list(p.fixed):
        in_ab = any(e.matrix in "AB" for e, _ in p.parameter_entries(name))
        value = values.get(name, p.parameters[name])
        scaled[name] = value * k if in_ab else value
    profile = p.with_values(scaled, name=f"{p.name} (frequencies x {k:g})")
    return LinearModel(profile)


def model_set(model: LinearModel, frequencies=(0.6, 0.77, 1.0, 1.3, 1.6), draws: int = 0,
              spread: float = PERTURBATION, seed: int = 0) -> tuple[list[LinearModel], list[str]]:
    """Models around the a priori: for each frequency scale k, the scaled a priori and ``draws``
    copies with every free derivative also scaled by a factor uniform in 1 -/+ ``spread``.
    Returns (models, labels); the a priori itself (k = 1, no draw) comes first when k = 1 is listed."""
    if not 0 <= spread < 1:
        raise DesignError(f"perturbation spread must be in [0, 1), got {spread:g}")
    rng = np.random.default_rng(seed)
    ks = sorted(float(k) for k in frequencies)
    ks.sort(key=lambda k: k != 1.0)  # the a priori first
    models, labels = [], []
    for k in ks:
        base = model if k == 1.0 else frequency_scaled(model, k)
        models.append(base)
        labels.append("a priori" if k == 1.0 else f"freq x{k:g}")
        for d in range(draws):
            f = rng.uniform(1 - spread, 1 + spread, len(model.theta))
            models.append(base.with_theta(base.theta * f))
            labels.append(f"freq x{k:g}, derivs draw {d + 1}")
    return models, labels


def design_set(model: LinearModel, seed: int = 1, draws: int = 4) -> tuple[list[LinearModel], list[str]]:
    """The designer's default robust set (5 + ``draws`` models): the a priori at frequency scales
    0.6, 0.77, 1, 1.3, 1.6, and ``draws`` models with derivatives x U(0.7, 1.3) at log-uniform
    random scales."""
    models, labels = model_set(model)
    rng = np.random.default_rng(seed)
    lo, hi = np.log(FREQUENCY_RANGE)
    for d in range(draws):
        k = float(np.exp(rng.uniform(lo, hi)))
        f = rng.uniform(1 - PERTURBATION, 1 + PERTURBATION, len(model.theta))
        base = frequency_scaled(model, k)
        models.append(base.with_theta(base.theta * f))
        labels.append(f"freq x{k:.2f}, derivs draw {d + 1}")
    return models, labels


def evaluation_set(model: LinearModel, seed: int = 101) -> tuple[list[LinearModel], list[str]]:
    """The set every comparison reports its worst case over (20 models, drawn apart from the
    designer's): frequency scales 0.6, 0.77, 1, 1.3, 1.6, each with the a priori derivatives and
    three draws of derivatives x U(0.7, 1.3)."""
    return model_set(model, draws=3, seed=seed)
