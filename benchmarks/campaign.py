"""A test campaign at size: 200 synthetic test points x 4 runs, serial, 2 local workers, Dask.

The campaign (:mod:`campaign.synthetic`): the Navion over 35..80 m/s, derivatives varying with
airspeed, 3 fitted runs of 20 s at 50 Hz per point (3211s and a doublet on the elevator) plus one
held-out run (about 0.25 s of ML per point on one core: small enough for minutes in all, large
enough that Dask's ~20 ms of scheduling per task stays a small part of it on 2 cores), 3 % measurement noise, 0.3 m/s vertical turbulence, an undeclared 0.15 s control
delay at every 20th point; ML on every point. Measured, each command in its own coordinator
process (``python -m campaign identify``), the machine's load average printed beside each:

1. wall time serial, with 2 local workers, with a Dask LocalCluster of 2 workers (the points'
   work, and the engine's start apart); throughput ratio against serial (target >= 1.8 with 2
   workers on 2 cores: on a shared machine the ratio is depressed by the others' load);
2. every stored record identical in all three (bit for bit, wall time aside);
3. the coordinator's peak memory (its own maximum resident set) for 50 and for 200 points;
4. killed half-way (SIGKILL to the coordinator and its workers) and resumed: no finished point
   recomputed (their files untouched), none lost, results equal to the uninterrupted run;
5. ``campaign stitch --hold-out 3``: the stitched model on 3 held-out airspeeds against each
   point's own model (target: within 10 %).

    nice -n 10 .venv/bin/python benchmarks/campaign.py [POINTS] > campaign-bench.txt 2>&1   # --help: options

Writes about 130 MB (the synthetic runs, kept for a re-run, and every executor's records) under
benchmarks/output/campaign/.
"""
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from campaign.synthetic import write_campaign  # noqa: E402
from _cli import counted  # noqa: E402

OUT = ROOT / "benchmarks" / "output" / "campaign"
SMALL = 50


def load() -> str:
    return "load average %.2f %.2f %.2f" % os.getloadavg()


def cli(*args, wait=True):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "campaign", *map(str, args), "--no-progress"] if args[0] == "identify" else \
        [sys.executable, "-m", "campaign", *map(str, args)]
    if not wait:
        return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                start_new_session=True)
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if proc.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)} failed:\n{proc.stdout}\n{proc.stderr}")
    return proc


def last_stats(out: Path) -> dict:
    return json.loads((out / "runs.jsonl").read_text().splitlines()[-1])


def records(out: Path) -> dict:
    recs = {p.stem: json.loads(p.read_text()) for p in (out / "points").glob("*.json")}
    for r in recs.values():
        r.pop("seconds")
    return recs


def identify(manifest: Path, out: Path, *executor) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    before = load()
    t = time.perf_counter()
    proc = cli("identify", manifest, "--out", out, *executor)
    wall = time.perf_counter() - t
    stats = last_stats(out)
    line = next(l for l in proc.stdout.splitlines() if l.startswith("coordinator peak memory"))
    stats.update(process_wall_s=wall, load_before=before, load_after=load(),
                 peak_total_mb=float(line.split()[3]))
    return stats


def subset(manifest: Path, count: int) -> Path:
    """A manifest of ``count`` of the points (every k-th), beside the full one."""
    text = manifest.read_text()
    head, *points = text.split("[[point]]")
    step = max(1, len(points) // count)
    small = manifest.with_name(f"campaign_{count}.toml")
    small.write_text(head + "".join("[[point]]" + p for p in points[::step][:count]))
    return small


def truth_ratio(manifest: Path, name: str) -> float:
    """Prediction error of the true model at a point over the point's own model's, on all its runs."""
    from campaign.manifest import load_manifest
    from campaign.point import prediction_error
    from campaign.synthetic import truth
    from identify.data.io import read_run_files
    from identify.model.profile import parse_profile

    point = next(p for p in load_manifest(manifest).points if p.name == name)
    rec = next(json.loads(f.read_text()) for f in (OUT / "serial" / "points").glob("*.json")
               if json.loads(f.read_text())["point"] == name)
    own = parse_profile(rec["identified_profile"])
    runs = read_run_files(rec["runs"] + rec["validate"], None, own)
    return prediction_error(truth(point.condition["airspeed"]), runs) / prediction_error(own, runs)


def main(n_points: int = 200) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    data = OUT / "data"
    t = time.perf_counter()
    if not (data / f"done_{n_points}_50hz").exists():
        shutil.rmtree(data, ignore_errors=True)
        write_campaign(data, np.linspace(35, 80, n_points), runs=4, seed=7, duration=20.0, dt=0.02,
                       undeclared=tuple(range(10, n_points, 20)))
        (data / f"done_{n_points}_50hz").touch()
    manifest = data / "campaign.toml"
    print(f"campaign: {n_points} points x 4 runs of 20 s at 50 Hz (3 fitted, 1 held out), ML; data ready in "
          f"{time.perf_counter() - t:.0f} s; {os.cpu_count()} CPUs; {load()}", flush=True)

    print("\n1. wall time (points' work; engine start apart)", flush=True)
    configs = {"serial": ["--executor", "serial"], "local 2": ["--executor", "local", "--workers", "2"],
               "dask 2": ["--dask", "--workers", "2"]}
    runs = {}
    for name, args in configs.items():
        s = runs[name] = identify(manifest, OUT / name.replace(" ", "_"), *args)
        print(f"  {name:<8} {s['seconds']:7.1f} s for {s['computed']} points (+{s['startup_s']:.1f} s start; "
              f"process {s['process_wall_s']:.1f} s); {s['failed']} failed; peak memory {s['peak_rss_mb']:.0f} MB; "
              f"{s['load_before']} -> {s['load_after']}", flush=True)
    base = runs["serial"]
    for name in ("local 2", "dask 2"):
        s = runs[name]
        print(f"  throughput {name} / serial: {base['seconds'] / s['seconds']:.2f}x (points' work), "
              f"{base['process_wall_s'] / s['process_wall_s']:.2f}x (whole command, start included) "
              f"[target >= 1.8x]", flush=True)

    print("\n2. identical results", flush=True)
    ref = records(OUT / "serial")
    for name in ("local 2", "dask 2"):
        other = records(OUT / name.replace(" ", "_"))
        same = other == ref
        print(f"  {name} == serial: {same} ({len(other)} records, {len(ref)} serial)", flush=True)

    print("\n3. coordinator peak memory", flush=True)
    small = subset(manifest, SMALL)
    for name, args in (("local 2", configs["local 2"]), ("dask 2", configs["dask 2"])):
        s = identify(small, OUT / f"{name.replace(' ', '_')}_{SMALL}", *args)
        print(f"  {name}: {SMALL} points {s['peak_rss_mb']:.0f} MB, {n_points} points "
              f"{runs[name]['peak_rss_mb']:.0f} MB while identifying; with the report and table written: "
              f"{s['peak_total_mb']:.0f} MB and {runs[name]['peak_total_mb']:.0f} MB "
              f"[target < 500 MB, independent of the count]", flush=True)

    print("\n4. killed half-way and resumed (local, 2 workers)", flush=True)
    out = OUT / "killed"
    shutil.rmtree(out, ignore_errors=True)
    proc = cli("identify", manifest, "--out", out, "--workers", "2", wait=False)
    folder = out / "points"
    while len(list(folder.glob("*.json")) if folder.exists() else []) < n_points // 2:
        if proc.poll() is not None:
            sys.exit("the campaign ended before it could be killed")
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    time.sleep(0.5)
    before = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in folder.glob("*.json")}
    leftovers = list(folder.glob(".*.tmp"))
    print(f"  killed with {len(before)} of {n_points} points stored ({len(leftovers)} partial writes left)", flush=True)
    cli("identify", manifest, "--out", out, "--workers", "2")
    s = last_stats(out)
    untouched = all(p.stat().st_mtime_ns == m and p.read_bytes() == c for p, (m, c) in
                    ((folder / n, v) for n, v in before.items()))
    after = records(out)
    print(f"  resumed: {s['already_done']} already stored, {s['computed']} computed "
          f"(expected {n_points - len(before)}); finished records untouched: {untouched}; "
          f"{len(after)} records; equal to the uninterrupted run: {after == ref}", flush=True)

    print("\n5. stitched model on 3 held-out airspeeds (campaign stitch --hold-out 3)", flush=True)
    proc = cli("stitch", manifest, "--out", OUT / "serial", "--hold-out", "3")
    print("  " + proc.stdout.strip().replace("\n", "\n  "), flush=True)
    print("  reference, the true model on the same runs (the best a stitch can do; the own model, fitted to "
          "turbulent runs, can beat it):")
    for c in json.loads((OUT / "serial" / "stitch" / "stitch.json").read_text())["verification"]:
        if "ratio" in c:
            print(f"    {c['point']}: truth / own model x{truth_ratio(manifest, c['point']):.3f} "
                  f"(stitched / own x{c['ratio']:.3f})", flush=True)
    print(f"\nreport: {OUT / 'serial' / 'report.md'}; {load()}")


def parser():
    return counted(__doc__, "points", 200, f"test points in the campaign (the memory figure also at {SMALL})")


if __name__ == "__main__":
    main(parser().parse_args().points)
