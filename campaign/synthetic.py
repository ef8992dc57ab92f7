"""A synthetic test campaign: a light aircraft flown at many airspeeds, written as a manifest.

The aircraft is the Navion of ``profiles/navion_cruise_long.toml`` (longitudinal: ``u, w, q,
theta``, elevator ``delta_e``) at its 53.6 m/s reference. Its dimensional derivatives change with
airspeed ``V`` as they physically do at constant density and lift-curve slope: force and moment
derivatives per unit velocity (``X_u, X_w, Z_u, Z_w, M_u, M_w, M_q``) in proportion to ``V``,
control derivatives (``Z_delta_e, M_delta_e``) to ``V^2`` (dynamic pressure), and the kinematic
``Z_q = V``; a mild compressibility-like term ``1 + 0.15 (V/V0 - 1)^2`` on the pitch damping keeps
the trends from being pure power laws. Trim: the pitch attitude and elevator that hold 1 g fall as
``1/V^2`` (lift coefficient).

Every run is simulated exactly (ZOH) from the truth at its point, with a 3211 or doublet on the
elevator, white measurement noise, Dryden-like turbulence (first-order filtered vertical gust
entering through the ``*_w`` derivatives) and, at a few points, an *undeclared effect*: a control
delay that no a priori model declares, so that those points break the smooth trends.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from identify.data.runs import Run
from identify.model.linear import LinearModel
from identify.model.profile import DOT, load_profile
from identify.model.simulate import simulate

V0 = 53.645  # m/s, the reference profile's airspeed
PROFILE = "navion_cruise_long"
PER_V = ("X_u", "X_w", "Z_u", "Z_w", "M_u", "M_w", "M_q")
PER_V2 = ("Z_delta_e", "M_delta_e")
THETA_TRIM0, DELTA_E_TRIM0 = 0.02, -0.03  # rad at V0 (reasoned: cruise incidence 1.1 deg, trim elevator)


def truth(airspeed: float):
    """The aircraft's true profile at ``airspeed`` (m/s)."""
    base = load_profile(PROFILE)
    s = airspeed / V0
    values = {k: v * s for k, v in base.free.items() if k in PER_V}
    values.update({k: v * s * s for k, v in base.free.items() if k in PER_V2})
    values["M_q"] *= 1 + 0.15 * (s - 1) ** 2
    values["Z_q"] = airspeed
    return base.with_values(values, name=f"Navion truth at {airspeed:g} m/s")


def trim(airspeed: float) -> dict[str, float]:
    """Trim pitch attitude and elevator (rad) at ``airspeed``: both scale with the lift
    coefficient, ``(V0/V)^2``."""
    c = (V0 / airspeed) ** 2
    return {"theta": THETA_TRIM0 * c, "delta_e": DELTA_E_TRIM0 * c}


def apriori(airspeed: float):
    """The a priori model a test team would start from: the reference Navion with only the
    kinematic ``Z_q`` moved to the point's airspeed (the aerodynamic derivatives left at their
    53.6 m/s values, so the estimator has real work to do away from the reference)."""
    return load_profile(PROFILE).with_values({"Z_q": airspeed}, name=f"Navion a priori at {airspeed:g} m/s")


def elevator_input(kind: str, width: float, amplitude: float, time: np.ndarray, start: float = 1.0) -> np.ndarray:
    """A 3211 (``3211``) or doublet (``doublet``) on the elevator (rad), from ``start`` s."""
    pulses = {"3211": (3, -2, 1, -1), "doublet": (1, -1)}[kind]
    edges = start + width * np.cumsum([0] + [abs(p) for p in pulses])
    u = np.zeros_like(time)
    for (a, b), p in zip(zip(edges[:-1], edges[1:]), pulses):
        u[(time >= a - 1e-9) & (time < b - 1e-9)] = amplitude * math.copysign(1, p)
    return u


def gust(time: np.ndarray, sigma: float, length: float, airspeed: float, rng) -> np.ndarray:
    """Vertical gust (m/s): white noise through a first-order filter with the Dryden break
    frequency ``V / L``, scaled to standard deviation ``sigma``."""
    dt = time[1] - time[0]
    a = math.exp(-airspeed / length * dt)
    e = rng.standard_normal(len(time)) * sigma * math.sqrt(1 - a * a)
    w = np.empty(len(time))
    w[0] = sigma * rng.standard_normal()
    for k in range(1, len(time)):
        w[k] = a * w[k - 1] + e[k]
    return w


def simulate_point_run(airspeed: float, kind: str, width: float, amplitude: float, seed: int, *,
                       duration: float = 15.0, dt: float = 0.05, noise: float = 0.03,
                       turbulence: float = 0.3, delay: float = 0.0) -> Run:
    """One run at ``airspeed``: elevator ``kind`` input, ``noise`` (fraction of each output's
    spread) white measurement noise, ``turbulence`` (m/s) vertical gust, ``delay`` (s) an
    undeclared control delay."""
    rng = np.random.default_rng(seed)
    model = LinearModel(truth(airspeed))
    p = model.profile
    time = np.arange(0.0, duration + dt / 2, dt)
    u = elevator_input(kind, width, amplitude, time)
    felt = u if delay == 0 else np.interp(time - delay, time, u, left=0.0)
    w_gust = gust(time, turbulence, 300.0, airspeed, rng) if turbulence else np.zeros_like(time)
    # the gust moves the air, not the aircraft: its effect is the w-column of A acting on -w_gust
    disturbance = -np.outer(w_gust, model.A[:, p.state_names.index("w")])
    sim = simulate(model, felt[:, None], dt, w=disturbance)
    channels = {"delta_e": u}
    for j, s in enumerate(p.state_names):
        channels[s] = sim.x[:, j]
        channels[s + DOT] = sim.xdot[:, j]
    for name in list(channels):
        if name != "delta_e":
            channels[name] = channels[name] + noise * np.std(channels[name]) * rng.standard_normal(len(time))
    meta = {"source": "simulation (pseudostep campaign.synthetic)", "airspeed": f"{airspeed:g} m/s",
            "input": f"{kind} width {width:g} s amplitude {amplitude:g} rad", "seed": str(seed),
            "noise_fraction": str(noise), "turbulence": f"{turbulence:g} m/s"}
    return Run(time, channels, meta, source=f"<synthetic {airspeed:g} m/s>")


RUN_PLAN = (("3211", 0.6, 0.03), ("3211", 0.9, -0.025), ("doublet", 1.2, 0.04), ("3211", 0.45, -0.035))


def write_campaign(out: str | Path, airspeeds, *, runs: int = 4, seed: int = 0, undeclared=(),
                   delay: float = 0.15, noise: float = 0.03, turbulence: float = 0.3, duration: float = 15.0,
                   dt: float = 0.05, method: str = "ml", validate_last: bool = True) -> Path:
    """Simulate a campaign into ``out``: per point a folder of ``runs`` run CSVs and its a priori
    profile, and ``campaign.toml`` listing them (the last run of each point held out for
    validation when ``validate_last``). Points whose index is in ``undeclared`` carry an
    undeclared ``delay`` s control delay; runs of ``duration`` s sampled every ``dt`` s. Returns the manifest's path; ``truth.csv`` beside it
    holds the true derivatives per point."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# synthetic campaign: Navion longitudinal over airspeed (campaign.synthetic)",
             "[campaign]", 'name = "Navion airspeed sweep (synthetic)"', f'method = "{method}"',
             "refine = false", 'condition = "airspeed"', ""]
    truth_rows = []
    for i, v in enumerate(airspeeds):
        name = f"P{i:03d}_V{v:05.1f}".replace(".", "_")
        folder = out / name
        folder.mkdir(exist_ok=True)
        apriori(v).save(folder / "apriori.toml")
        files = []
        for k in range(runs):
            kind, width, amp = RUN_PLAN[k % len(RUN_PLAN)]
            run = simulate_point_run(v, kind, width, amp, seed * 100003 + i * 101 + k, duration=duration,
                                     dt=dt, noise=noise, turbulence=turbulence,
                                     delay=delay if i in undeclared else 0.0)
            path = folder / f"run{k + 1}.csv"
            run.to_csv(path)
            files.append(path.name)
        fit, val = (files[:-1], files[-1:]) if validate_last and runs > 1 else (files, [])
        t = trim(v)
        lines += ["[[point]]", f'name = "{name}"', f"airspeed = {v:.6g}",
                  f"trim_theta = {t['theta']:.6g}", f"trim_delta_e = {t['delta_e']:.6g}",
                  f'profile = "{name}/apriori.toml"',
                  "runs = [" + ", ".join(f'"{name}/{f}"' for f in fit) + "]"]
        if val:
            lines.append("validate = [" + ", ".join(f'"{name}/{f}"' for f in val) + "]")
        lines.append("")
        truth_rows.append((name, v, truth(v).free, i in undeclared))
    manifest = out / "campaign.toml"
    manifest.write_text("\n".join(lines))
    names = list(truth_rows[0][2])
    with open(out / "truth.csv", "w") as f:
        f.write(",".join(["point", "airspeed", "undeclared_delay"] + names) + "\n")
        for name, v, values, bad in truth_rows:
            f.write(",".join([name, f"{v:.6g}", f"{delay if bad else 0:g}"] + [f"{values[n]:.8g}" for n in names]) + "\n")
    return manifest
