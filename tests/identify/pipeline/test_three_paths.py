"""One job, three callers: ``identify estimate``, ``campaign identify`` and ``identify.Job`` give
the same result.json (provenance aside), bit for bit, on a refined profile with a state-built
term (q|q|): all three fit it from the model's simulated states, as refine did."""
import json

from campaign.executors import Serial
from campaign.manifest import load_manifest
from campaign.runner import run_campaign
from identify import Job
from identify.cli import main
from identify.model.profile import parse_profile
from identify.refine.candidates import Nonlinear
from tests.identify.refine.test_refine import PROFILE, nonlinear_runs


def _without_provenance(result: dict) -> dict:
    result = json.loads(json.dumps(result))
    assert result["info"].pop("provenance")["runs"]  # there, and set aside: it names the caller's paths
    return result


def test_cli_campaign_and_api_give_the_same_result_json(tmp_path, capsys):
    fit, _ = nonlinear_runs(-20.0, noise=0.10)
    profile = parse_profile(Nonlinear("M", "q_absq", ("q",), "absq").profile(PROFILE, {"M_q_absq": -10.0}).to_toml())
    toml = profile.save(tmp_path / "final_profile.toml")
    files = [str(r.to_csv(tmp_path / f"run{i}.csv", ["eta", "u", "q", "theta"])) for i, r in enumerate(fit)]

    assert main(["estimate", *files, "--profile", str(toml), "--method", "ml", "--out", str(tmp_path / "cli")]) == 0
    assert "q_absq built from the model's simulated states" in capsys.readouterr().err
    cli = json.loads((tmp_path / "cli" / "result.json").read_text())

    Job(files, str(toml), method="ml").estimate().save(tmp_path / "api")
    api = json.loads((tmp_path / "api" / "result.json").read_text())

    manifest = tmp_path / "campaign.toml"
    manifest.write_text(f'[campaign]\nmethod = "ml"\nprofile = "final_profile.toml"\n'
                        f'[[point]]\nname = "one"\nruns = {json.dumps([f.rsplit("/", 1)[1] for f in files])}\n')
    assert run_campaign(load_manifest(manifest), tmp_path / "campaign", Serial(), progress=False)["failed"] == 0
    record = json.loads(next((tmp_path / "campaign" / "points").glob("*.json")).read_text())

    assert cli["parameters"]["M_q_absq"]["value"] != profile.free["M_q_absq"]  # a fit happened
    assert "feedback" in cli["info"]["standard_errors"]  # the state-term fit's bounds, not a plain fit's
    assert _without_provenance(api) == _without_provenance(cli)
    assert _without_provenance(record["result"]) == _without_provenance(cli)
