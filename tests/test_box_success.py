"""experiments/box_success.py: a goal-space learner's own top box and its success at the end of training."""

import pytest
from box_success import box_at_end


def _line(epoch: int, success: float, volume: float) -> dict:
    return {"epoch": epoch, "env_steps": 100.0 * epoch,
            "levels": [{"volume": 1.0, "half_width": [0.5], "success": 1.0},
                       {"volume": volume, "half_width": [volume / 2], "success": success}]}


def test_the_top_box_of_the_last_epoch_and_success_over_the_final_epochs():
    lines = [_line(e, 0.0 if e <= 3 else 1.0 if e % 2 else 0.5, float(e)) for e in range(1, 8)]
    box = box_at_end(lines, 4)  # epochs 4-7: successes 0.5, 1, 0.5, 1
    assert box["epoch"] == 7 and box["env_steps"] == 700.0
    assert box["volume"] == 7.0 and box["half_width"] == [3.5]
    assert box["success_mean"] == pytest.approx(0.75) and box["success_std"] == pytest.approx(0.25)
    assert box["epochs_averaged"] == 4
    assert box_at_end(lines, 100)["epochs_averaged"] == 7  # a short run averages what it has


def test_a_flat_learner_has_no_box_and_last_must_be_positive():
    assert box_at_end([{"epoch": 1, "env_steps": 10.0, "skill_loss": 0.1}], 20) is None
    with pytest.raises(SystemExit, match="last: must be >= 1; got 0"):
        box_at_end([_line(1, 1.0, 1.0)], 0)


def test_new_runs_join_the_rows_of_runs_no_longer_on_disk(tmp_path):
    import json

    from box_success import Args, main

    run = tmp_path / "run-s1"
    run.mkdir()
    (run / "metrics.jsonl").write_text("".join(json.dumps(_line(e, 1.0, 4.0)) + "\n" for e in range(1, 4)))
    rows = tmp_path / "rows.json"
    rows.write_text(json.dumps({"rows": [{"preset": "p", "seed": 1, "run_dir": str(run)},
                                         {"preset": "p", "seed": 0, "run_dir": str(tmp_path / "gone")}]}))
    out = tmp_path / "box.json"
    out.write_text(json.dumps({"rows": [{"preset": "p", "seed": 0, "volume": 9.0},
                                        {"preset": "p", "seed": 1, "volume": 1.0}]}))
    main(Args(rows=(str(rows),), out=str(out)))
    kept = {r["seed"]: r["volume"] for r in json.loads(out.read_text())["rows"]}
    assert kept == {0: 9.0, 1: 4.0}  # seed 0's run is gone and keeps its row; seed 1 is recounted
