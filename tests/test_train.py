"""train.py end to end (quick profile shrunk with --set, C backend) and its argument checks."""

from __future__ import annotations

import json
import pathlib
import sys

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))
import train  # noqa: E402

SMALL = ["--set", "tl_epochs=20", "--set", "tl_seeds=2", "--set", "tl_hidden=5,20",
         "--set", "tl_replication=1,20", "--set", "al_seeds=2", "--set", "al_phase1=10",
         "--set", "al_phase2=10", "--set", "al_no_tricks=40",
         "--set", "an_seeds=2", "--set", "an_tl_epochs=20"]


def test_train_writes_report_metrics_and_every_figure(tmp_path):
    assert train.main(["--out", str(tmp_path), *SMALL]) == 0
    data = json.loads((tmp_path / "metrics.json").read_text())
    rows = {(r["action"], r["position"]): r for r in data["scripted_episodes"]}
    assert len(rows) == 6
    for pos in ("left", "middle", "right"):
        assert rows["point", pos]["final_point_l1"] < 0.01
        assert rows["push", pos]["target_moved_m"] > 0.02
        assert rows["push", pos]["others_moved_m"] < 1e-3
    tl = data["tl"]
    assert tl["accuracy"]["epochs"] == 20 and tl["accuracy"]["seeds"] == 2
    assert [p["hidden"] for p in tl["fig6"]["points"]] == [5, 20]
    assert 0.0 <= tl["accuracy"]["test_acc_mean"] <= 1.0
    report = (tmp_path / "REPORT.md").read_text()
    assert "| test accuracy, H=50, n=20 | ~95% |" in report and "| push | left |" in report
    for name in ("accuracy", "fig6", "fig7", "noise", "noise_fresh"):
        assert (tmp_path / "tl" / f"{name}.png").stat().st_size > 1000
        assert f"tl/{name}.png" in report
    al = data["al"]
    assert al["seeds"] == 2 and set(al["success"]) == {"20"}
    for rates in (al["final"]["home"]["by_action"], al["final"]["random_starts"]["by_action"]):
        assert set(rates) == {"point", "touch", "push"}
        assert all(0.0 <= v <= 1.0 for v in rates.values())
    assert "| point, from home |" in report
    for name in ("fig10", "fig11", "fig13", "fig14", "fig14_paper_schedule"):
        assert (tmp_path / "al" / f"{name}.png").stat().st_size > 1000
        assert f"al/{name}.png" in report
    an = data["an"]
    assert an["seeds"] == 2 and len(an["test"]["acc_per_seed"]) == 2
    assert all(0.0 <= an[k]["acc_mean"] <= 1.0 for k in ("train", "test", "test_random"))
    assert "| train accuracy | > 99% |" in report
    for name in ("fig15", "fig12"):
        assert (tmp_path / "an" / f"{name}.png").stat().st_size > 1000
        assert f"an/{name}.png" in report
    assert not list(tmp_path.rglob("*.tmp"))
    # the report can be rebuilt from metrics.json alone, identically
    (tmp_path / "REPORT.md").unlink()
    assert train.main(["--out", str(tmp_path), "--report-only"]) == 0
    assert (tmp_path / "REPORT.md").read_text() == report
    assert train.main(["--out", str(tmp_path / "nothing"), "--report-only"]) == 2


@pytest.mark.parametrize("argv, field", [
    (["--profile", "huge"], "--profile"),
    (["--backend", "ode"], "--backend"),
    (["--set", "tl_epoch=5"], "tl_epoch"),
    (["--set", "tl_seeds=0"], "tl_seeds"),
    (["--set", "tl_hidden=a,b"], "tl_hidden"),
    (["--set", "al_phase1=0", "--set", "al_phase2=0"], "al_phase"),
    (["--set", "al_seeds=0"], "al_seeds"),
])
def test_train_rejects_bad_arguments(argv, field, capsys):
    with pytest.raises(SystemExit):
        train.parse_args(argv)
    assert field in capsys.readouterr().err
