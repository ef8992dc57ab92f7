"""Writes the sample raw files of docs/real_data.md: one synthetic flight (identify.compat.synthetic:
alpha vane with bias 1 deg, scale 1.05 and a 60 ms skew, q gyro biased 0.2 deg/s, sensor noise,
light turbulence) in the four layouts flight-test data arrive in, in flight-test units:

* ``flight_header.csv`` - CSV with a header, units in brackets (g, deg/s, KTAS, deg, ft);
* ``flight.asc`` - whitespace text without a header or time column (25 Hz), columns named by the map;
* ``flight_struct.mat`` - MATLAB v5 with a struct ``flight`` of one field per channel;
* ``de3211.mat``, ``de3211b.mat`` - MATLAB data matrices named after their files (two flights),
  columns numbered 1-based in the map as MATLAB numbers them.

Run from the repository root: ``python examples/real_data/make_real_data.py``.
"""
from pathlib import Path

import numpy as np
from scipy.io import savemat

from identify.compat.synthetic import flight

HERE = Path(__file__).resolve().parent
DT, DURATION = 0.04, 20.0
G0, KT, FT = 9.80665, 1852 / 3600, 0.3048
# column: (run channel, factor from SI to the file's unit)
COLUMNS = {"ax": ("a_x", 1 / G0), "ay": ("a_y", 1 / G0), "az": ("a_z", 1 / G0), "p": ("p", 180 / np.pi),
           "q": ("q", 180 / np.pi), "r": ("r", 180 / np.pi), "vt": ("V", 1 / KT), "alpha": ("alpha", 180 / np.pi),
           "beta": ("beta", 180 / np.pi), "phi": ("phi", 180 / np.pi), "theta": ("theta", 180 / np.pi),
           "psi": ("psi", 180 / np.pi), "alt": ("h", 1 / FT), "de": ("de", 180 / np.pi)}
UNITS = {"ax": "g", "ay": "g", "az": "g", "p": "deg/s", "q": "deg/s", "r": "deg/s", "vt": "KTAS", "alpha": "deg",
         "beta": "deg", "phi": "deg", "theta": "deg", "psi": "deg", "alt": "ft", "de": "deg"}


def table(seed: int) -> tuple[np.ndarray, np.ndarray]:
    measured, _ = flight(duration=DURATION, dt=DT, gust_deg=0.1, seed=seed)
    return measured.time, np.column_stack([measured[ch] * f for ch, f in COLUMNS.values()])


def main():
    t, data = table(seed=0)
    names = list(COLUMNS)
    header = ",".join(["time [s]"] + [f"{n} [{UNITS[n]}]" for n in names])
    np.savetxt(HERE / "flight_header.csv", np.column_stack([t, data]), delimiter=",", fmt="%.7g", header=header,
               comments="")
    np.savetxt(HERE / "flight.asc", data, fmt="%.7g")
    savemat(HERE / "flight_struct.mat", {"flight": {"t": t, **{n: data[:, j] for j, n in enumerate(names)}}})
    for stem, seed in (("de3211", 0), ("de3211b", 1)):
        t, data = table(seed)
        savemat(HERE / f"{stem}.mat", {stem: np.column_stack([t, data])})


if __name__ == "__main__":
    main()
