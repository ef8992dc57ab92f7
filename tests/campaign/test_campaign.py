"""The test campaign: manifest, resume, failures, executors (a real Dask LocalCluster), stitch."""
import json
import os
import signal

import numpy as np
import pytest

from campaign.executors import DaskExecutor, LocalPool, Serial
from campaign.manifest import load_manifest
from campaign.report import write_report
from campaign.runner import run_campaign
from campaign.store import Store
from campaign.synthetic import write_campaign
from identify.errors import CampaignError, ProfileError
from tests.helpers import one_error_line, run_cli

SPEEDS = np.linspace(35, 80, 8)


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """8 points x 3 runs (2 fitted, 1 held out), a control delay nobody declared at point 3."""
    return write_campaign(tmp_path_factory.mktemp("camp"), SPEEDS, runs=3, duration=10.0, undeclared=(3,))


@pytest.fixture(scope="module")
def serial_records(synthetic, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    stats = run_campaign(load_manifest(synthetic), out, Serial(), progress=False)
    assert stats["computed"] == len(SPEEDS) and stats["failed"] == 0
    return _records(out)


def _records(out):
    """{key: record} without the wall time (the one field that may differ between runs)."""
    recs = {p.stem: json.loads(p.read_text()) for p in (out / "points").glob("*.json")}
    for r in recs.values():
        r.pop("seconds")
    return recs


def test_manifest_toml_and_csv_matrix_agree_and_nothing_is_code(synthetic, tmp_path):
    camp = load_manifest(synthetic)
    assert len(camp.points) == len(SPEEDS) and camp.method == "ml" and camp.trend_condition == "airspeed"
    p0 = camp.points[0]
    assert p0.trim and set(p0.trim) == {"theta", "delta_e"} and len(p0.files("runs")) == 2
    rows = ["point,airspeed,label,profile,runs,validate"]
    rows += [f"{p.name},{p.condition['airspeed']},__import__('os').remove('x'),{p.profile_path()},"
             f"{p.root}/{p.name}/run*.csv,{p.root}/{p.validate[0]}" for p in camp.points]
    matrix = tmp_path / "points.csv"
    matrix.write_text("\n".join(rows) + "\n")
    csv = load_manifest(matrix, method="ls")
    assert csv.method == "ls" and [p.name for p in csv.points] == [p.name for p in camp.points]
    assert csv.points[0].condition["label"] == "__import__('os').remove('x')"  # text, never evaluated
    assert len(csv.points[0].files("runs")) == 3  # the glob
    bad = tmp_path / "bad.toml"
    bad.write_text('[campaign]\nmethod = "nope"\n[[point]]\nruns = ["a.csv"]\nprofile = "navion_cruise_long"\n')
    with pytest.raises(CampaignError, match="unknown method 'nope'"):
        load_manifest(bad)


def test_resume_after_interruption_recomputes_nothing_finished(synthetic, tmp_path, serial_records):
    camp = load_manifest(synthetic)

    def interrupt_after_three(task, record, seen=[]):
        seen.append(task["key"])
        if len(seen) == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_campaign(camp, tmp_path, Serial(), progress=False, on_result=interrupt_after_three)
    first = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in (tmp_path / "points").glob("*.json")}
    assert len(first) == 3
    stats = run_campaign(camp, tmp_path, Serial(), progress=False)
    assert stats["already_done"] == 3 and stats["computed"] == len(SPEEDS) - 3
    for path, (mtime, content) in first.items():  # untouched: not recomputed, not rewritten
        assert path.stat().st_mtime_ns == mtime and path.read_bytes() == content
    assert _records(tmp_path) == serial_records  # none lost, the same results
    again = run_campaign(camp, tmp_path, Serial(), progress=False)
    assert again["computed"] == 0 and again["already_done"] == len(SPEEDS)


def test_failing_points_do_not_stop_the_campaign_and_lead_the_report(synthetic, tmp_path):
    camp = load_manifest(synthetic)
    text = synthetic.read_text()
    broken = camp.points[2]
    bad_file = synthetic.parent / broken.name / "broken.csv"
    bad_file.write_text("time,delta_e\n0,1\n0.05,oops\n")
    text = text.replace(f'runs = ["{broken.name}/run1.csv"', f'runs = ["{broken.name}/broken.csv"')
    text = text.replace(f'"{camp.points[5].name}/run1.csv"', '"no/such/file.csv"')
    manifest = synthetic.parent / "with_failures.toml"
    manifest.write_text(text)
    camp = load_manifest(manifest)
    stats = run_campaign(camp, tmp_path, Serial(), progress=False)
    assert stats["failed"] == 2
    recs = [json.loads(p.read_text()) for p in (tmp_path / "points").glob("*.json")]
    failed = {r["point"]: r["reason"] for r in recs if r["status"] == "failed"}
    assert set(failed) == {broken.name, camp.points[5].name}
    assert "broken.csv" in failed[broken.name] and "no/such/file.csv" in failed[camp.points[5].name]
    assert len(recs) == len(SPEEDS) and sum(r["status"] == "ok" for r in recs) >= len(SPEEDS) - 3
    report = write_report(camp, tmp_path).read_text()
    assert report.index("## Failures") < report.index("## Trends")
    failures = report[report.index("## Failures"):report.index("## Points that break")]
    assert failures.index(broken.name) < failures.index("not converged") if "not converged" in failures else True
    assert broken.name in failures and camp.points[5].name in failures
    assert "P003" in report[:report.index("## Trends")]  # the undeclared delay: not converged or off the trend


def test_local_pool_equals_serial_and_survives_a_killed_worker(synthetic, tmp_path, serial_records):
    pool = LocalPool(workers=2)
    killed = []

    def kill_one(task, record):
        if not killed:  # a worker dies while the others' points are in flight
            pid = next(iter(pool._pool._processes))
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    try:
        stats = run_campaign(load_manifest(synthetic), tmp_path, pool, progress=False, on_result=kill_one)
    finally:
        pool.close()
    assert killed and stats["failed"] == 0 and stats["computed"] == len(SPEEDS)
    assert _records(tmp_path) == serial_records


@pytest.fixture(scope="module")
def dask_executor():
    ex = DaskExecutor(workers=2)
    ex.start()
    yield ex
    ex.close()


def test_dask_local_cluster_on_loopback_equals_serial(synthetic, tmp_path, serial_records, dask_executor):
    info = dask_executor.client.scheduler_info()
    assert info["address"].startswith("tcp://127.0.0.1:")
    assert len(info["workers"]) == 2 and all(w.startswith("tcp://127.0.0.1:") for w in info["workers"])
    stats = run_campaign(load_manifest(synthetic), tmp_path, dask_executor, progress=False)
    assert stats["computed"] == len(SPEEDS) and stats["failed"] == 0
    assert _records(tmp_path) == serial_records  # bit-identical


def test_dask_worker_killed_mid_campaign_loses_nothing(synthetic, tmp_path, serial_records, dask_executor):
    pids = dask_executor.worker_pids()
    done = []

    def kill_after_first(task, record):
        done.append(task["key"])
        if len(done) == 1:
            os.kill(next(iter(pids.values())), signal.SIGKILL)

    stats = run_campaign(load_manifest(synthetic), tmp_path, dask_executor, progress=False,
                         on_result=kill_after_first)
    assert stats["computed"] == len(SPEEDS) and stats["failed"] == 0
    assert _records(tmp_path) == serial_records
    assert set(dask_executor.worker_pids().values()) != set(pids.values())  # the worker really died


def test_stitched_model_predicts_held_out_points_as_well_as_their_own(tmp_path, capsys):
    from campaign.cli import main as campaign_main
    from identify.cli import main as identify_main

    manifest = write_campaign(tmp_path / "c", np.linspace(35, 80, 16), runs=3, duration=12.0)
    out = tmp_path / "out"
    assert run_campaign(load_manifest(manifest), out, Serial(), progress=False)["failed"] == 0
    other = write_campaign(tmp_path / "other", [52.0], runs=4, seed=5)  # a held-out campaign, 1 point
    status = campaign_main(["stitch", str(manifest), "--out", str(out), "--hold-out", "2", "--check", str(other),
                            "--executor", "serial", "--no-progress"])
    checks = json.loads((out / "stitch" / "stitch.json").read_text())["verification"]
    assert [c["set"] for c in checks] == ["held out", "held out", "check"]
    assert status == (0 if all(c["within_10pct"] for c in checks) else 1), capsys.readouterr()
    assert all(c["ratio"] <= 1.10 for c in checks[:2])
    # on the check point (a turbulence realisation the own model was fitted to), the stitched model
    # predicts as well as the true aircraft does: the most any model of the envelope can do
    from campaign.point import prediction_error
    from campaign.synthetic import truth
    from identify.data.io import read_run_files
    point = load_manifest(other).points[0]
    runs = read_run_files(point.files("runs") + point.files("validate"))
    assert checks[2]["stitched_error"] <= 1.03 * prediction_error(truth(52.0), runs)
    stitched = out / "stitch" / "stitched_profile.toml"
    # the stitched (scheduled) profile as the a priori model of a next campaign: evaluated per point
    from campaign.runner import point_profile
    from identify.model.profile import load_profile
    from identify.model.schedule import at_condition
    nxt = load_manifest(other, profile=str(stitched))
    assert point_profile(nxt.points[0]).free == at_condition(load_profile(stitched), 52.0).free
    capsys.readouterr()
    assert identify_main(["model", str(stitched), "--at", "airspeed=50"]) == 0
    shown = capsys.readouterr().out
    assert "airspeed = 50" in shown and "trim:" in shown
    assert identify_main(["model", str(stitched), "--at", "airspeed=200"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "outside the schedule" in err[0]
    assert "## Stitched model" in (out / "report.md").read_text()
    header = (out / "results.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == ["point", "airspeed"] and {"parameter", "value", "std", "converged"} <= set(header)


def test_scheduled_profile_interpolates_and_never_extrapolates():
    from identify.model.profile import load_profile
    from identify.model.schedule import at_condition

    base = load_profile("navion_cruise_long")
    sched = base.with_values({})
    from dataclasses import replace
    sched = replace(sched, meta={"schedule": {"condition": "V", "at": [40.0, 60.0],
                                              "values": {"M_q": [-2.0, -3.0], "Z_q": [40.0, 60.0]},
                                              "std": {"M_q": [0.1, 0.3]}}})
    at = at_condition(sched, 45.0)
    assert at.free["M_q"] == pytest.approx(-2.25) and at.fixed["Z_q"] == pytest.approx(45.0)
    assert at.meta["std"]["M_q"] == pytest.approx(0.15) and "schedule" not in at.meta
    with pytest.raises(ProfileError, match="outside the schedule"):
        at_condition(sched, 61.0)


def test_design_writes_every_point_and_the_flight_time(tmp_path):
    from campaign.design import run_design

    manifest = tmp_path / "d.toml"
    manifest.write_text('[campaign]\nprofile = "navion_cruise_long"\n[[point]]\nname = "a"\nairspeed = 50\n'
                        '[[point]]\nname = "b"\nairspeed = 60\n')
    opts = dict(restarts=1, n_iter=30, kicks=0, nominal_kicks=0, record=12.0, duration=5.0)
    stats = run_design(load_manifest(manifest), tmp_path, Serial(), opts, progress=False)
    assert stats["designed"] == 2 and stats["flight_time_s"] == pytest.approx(24.0)
    assert (tmp_path / "designs" / "a.signals.json").exists()
    again = run_design(load_manifest(manifest), tmp_path, Serial(), opts, progress=False)
    assert again["computed"] == 0 and again["already_done"] == 1 and again["shared"] == 1  # one a priori model


def test_cli_bad_manifest_is_one_line(tmp_path, synthetic):
    bad = tmp_path / "m.toml"
    bad.write_text("[[point]]\nruns = 3\n")
    one_error_line(run_cli("campaign", "identify", bad, "--out", tmp_path / "o"), "runs")
    wrong = tmp_path / "wrong_option.toml"  # would fail every point: refused before any work
    wrong.write_text(synthetic.read_text().replace("[campaign]", "[options]\nmax_iterations = 3\n[campaign]", 1))
    one_error_line(run_cli("campaign", "identify", wrong, "--out", tmp_path / "o"), "max_iterations", "ml")
    assert not (tmp_path / "o" / "points").exists()
