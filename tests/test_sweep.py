"""`mjx-emp sweep` and `mjx-emp report` on the committed smoke spec: a sweep completes, a second
call trains nothing, a sweep stopped by SIGTERM says so in one line and called again (through
submitit's local executor) ends with the rows of one never stopped, one stopped while one of its two workers
is idle still ends, `mjx-emp eval` of a sweep's run gives its row again, the report prints IQM intervals, and bad specs are refused before anything trains."""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from tiny import cli_in_process, mjx_emp, run_cli

from mjx_emp.errors import ConfigError
from mjx_emp.run.evaluate import row_figures
from mjx_emp.run.rows import read_rows
from mjx_emp.run.specs import load_spec

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "experiments" / "smoke-point-mass.toml"


def sweep(tmp: Path, *extra: str) -> subprocess.CompletedProcess:
    return run_cli("sweep", str(SMOKE), "--runs", str(tmp / "runs"), "--results", str(tmp / "rows.jsonl"), *extra)


def comparable(row: dict) -> dict:
    """A row less what differs between two sweeps of the same spec by design: provenance (times,
    commands) and where its runs live."""
    figures = row_figures(row)
    figures.pop("run_dir")
    return figures


@pytest.fixture(scope="module")
def swept(tmp_path_factory) -> Path:
    """The smoke spec swept once, uninterrupted."""
    tmp = tmp_path_factory.mktemp("swept")
    result = sweep(tmp)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "4 row(s) written this call" in result.stdout
    return tmp


def test_a_sweep_writes_one_row_per_run_with_its_provenance(swept):
    rows = read_rows(swept / "rows.jsonl")
    spec = load_spec(SMOKE)
    assert [(r["row"], r["seed"]) for r in rows] == [(row.name, seed) for row in spec.rows for seed in row.seeds]
    for row in rows:
        assert row["spec"] == "smoke-point-mass" and row["schema"] == 1
        assert row["train"]["preset"] in ("point-mass-k1", "point-mass-k2")
        assert row["train"]["overrides"]["epochs"] in (2, 3) and row["train"]["config"]["seed"] == row["seed"]
        assert len(row["train"]["commit"]) == 40 and isinstance(row["train"]["dirty"], bool)
        assert row["train"]["versions"]["jax"] == row["evaluation"]["versions"]["jax"] != "unknown"
        assert row["train"]["machine"]["backend"] == "cpu" and row["train"]["wall_s"] > 0
        assert "mjx-emp sweep" in row["train"]["command"] and row["evaluation"]["seed"] == 0
        figures = row["figures"]
        assert figures["env_steps"] > 0 and figures["top_volume"] > 0 and 0 <= figures["top_success"] <= 1
        assert figures["phase2"]["episodes"] >= 16 and {"aimed", "random"} <= set(figures["phase2"])
        assert len(row["curves"]["env_steps"]) == figures["epoch"] == row["train"]["config"]["epochs"]
        assert len(row["curves"]["phase2_min_distance"]) == 2
    seeds = [row["figures"] for row in rows if row["row"] == "he-k1"]
    assert seeds[0] != seeds[1], "two seeds gave the same figures"


def test_a_second_call_trains_and_evaluates_nothing(swept):
    metrics = sorted((swept / "runs").rglob("metrics.jsonl"))
    before = [(p, p.stat().st_mtime_ns) for p in metrics]
    lines = (swept / "rows.jsonl").read_text().count("\n")
    result = sweep(swept)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "4 evaluated already, 0 to do" in result.stdout and "0 row(s) written" in result.stdout
    assert [(p, p.stat().st_mtime_ns) for p in metrics] == before
    assert (swept / "rows.jsonl").read_text().count("\n") == lines


def test_eval_of_a_sweep_run_gives_its_row(swept, tmp_path):
    (stored,) = [r for r in read_rows(swept / "rows.jsonl") if (r["row"], r["seed"]) == ("he-k2", 1)]
    out = tmp_path / "eval.json"
    result = cli_in_process("eval", stored["run_dir"], "--episodes", "16", "--seed", "0", "--out", str(out))
    assert result.returncode == 0, result.stderr[-2000:]
    (evaluated,) = json.loads(out.read_text())["runs"]
    assert {**row_figures(evaluated), "spec": stored["spec"], "row": stored["row"]} == row_figures(stored)
    assert evaluated["train"]["config"] == stored["train"]["config"]


def test_report_prints_iqm_intervals_and_writes_a_block(swept, tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# results\n<!-- report:smoke -->\nold\n<!-- /report:smoke -->\nafter\n")
    result = cli_in_process("report", str(SMOKE), "--results", str(swept / "rows.jsonl"), "--reps", "200",
                     "--into", str(page), "--block", "smoke")
    assert result.returncode == 0, result.stderr[-2000:]
    assert "IQM [95% CI]" in result.stdout and "P(phase-2 min distance better than he-k1)" in result.stdout
    he_k2 = next(line for line in result.stdout.splitlines() if line.startswith("| he-k2 |"))
    assert he_k2.count("[") >= 4 and "| 2 |" in he_k2  # an interval per metric, n = 2 seeds
    text = page.read_text()
    assert "old" not in text and text.endswith("<!-- /report:smoke -->\nafter\n") and "mjx-emp sweep" in text


def test_rows_made_before_a_config_field_existed_stay_current_and_a_changed_value_does_not(swept):
    """A stored row whose configs lack a field added since (dropped here from its records) still
    answers the spec: the field's default is what it ran with. A value that differs does not."""
    from mjx_emp.run.sweep import row_is_current

    spec, stored = load_spec(SMOKE), read_rows(swept / "rows.jsonl")[0]
    row = next(r for r in spec.rows if r.name == stored["row"])
    current = functools.partial(row_is_current, row=row, seed=stored["seed"], eval_seed=spec.run_eval_seed(stored["seed"]))
    assert current(stored)
    older = json.loads(json.dumps(stored))
    del older["train"]["config"]["flip_cost"], older["phase2_config"]["subgoal_reach"]
    assert current(older)
    changed = json.loads(json.dumps(stored))
    changed["phase2_config"]["subgoal_reach"] = 0.5
    assert not current(changed)
    unknown = {**stored, "train": {**stored["train"], "config": "unknown"}}
    assert not current(unknown)


def test_a_stopped_sweep_says_so_in_one_line_and_called_again_ends_with_the_same_rows(swept, tmp_path):
    """SIGTERM the sweep alone (not its worker) while the first row's seeds train: it passes the
    signal on, its worker stops training at a checkpoint, and the sweep exits 143 with one line
    saying how to resume, no traceback. Called again with submitit's local executor, the row
    resumes as one program and its rows equal the uninterrupted sweep's in every non-timing
    field. The spec is the smoke spec's first row (the one the signal lands in); the second row
    would train afresh as the uninterrupted sweep did."""
    spec = tmp_path / SMOKE.name
    spec.write_text(SMOKE.read_text().split('\n[[row]]\nname = "he-k2"')[0])
    process = subprocess.Popen(mjx_emp("sweep", str(spec), "--runs", str(tmp_path / "runs"), "--results",
                                       str(tmp_path / "rows.jsonl")),
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    first_epoch = tmp_path / "runs" / "smoke-point-mass" / "he-k1-s0" / "metrics.jsonl"
    deadline = time.monotonic() + 400
    while not (first_epoch.exists() and first_epoch.read_text().count("\n") >= 1):
        assert process.poll() is None and time.monotonic() < deadline, "the sweep ended before its first epoch"
        time.sleep(0.02)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 128 + signal.SIGTERM, stderr[-3000:]
    assert "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1, stderr[-3000:]
    assert stderr.startswith("mjx-emp: sweep smoke-point-mass stopped by SIGTERM with 0 of 2 runs evaluated; its "
                             "running jobs stopped at their newest checkpoints; `mjx-emp sweep "), stderr
    worker_log = (tmp_path / "runs" / "smoke-point-mass" / "logs" / "he-k1.log").read_text()
    assert "stopped by SIGTERM; the newest checkpoint is epoch" in worker_log, worker_log[-2000:]
    assert not (tmp_path / "rows.jsonl").exists() or not read_rows(tmp_path / "rows.jsonl")
    result = run_cli("sweep", str(spec), "--runs", str(tmp_path / "runs"), "--results", str(tmp_path / "rows.jsonl"),
                     "--executor", "submitit-local")
    assert result.returncode == 0, result.stderr[-3000:]
    rows = read_rows(tmp_path / "rows.jsonl")
    assert rows[0]["evaluation"]["did"][0].startswith("resumed seeds 0, 1 as one program")
    assert [r["row"] for r in rows] == ["he-k1", "he-k1"]
    assert [comparable(r) for r in rows] == [comparable(r) for r in read_rows(swept / "rows.jsonl") if r["row"] == "he-k1"]


def test_a_sweep_stopped_while_one_of_two_workers_is_idle_still_ends(tmp_path):
    """Two workers, and the first row's job over while the second still trains: SIGTERM to the
    sweep reaches both workers. The idle one lives through it (the pool shuts down in order
    instead of breaking and waiting on the other forever), the training one stops at a
    checkpoint, and the sweep exits 143 with the first row's row stored."""
    spec = tmp_path / SMOKE.name
    short, long = SMOKE.read_text().split('\n[[row]]\nname = "he-k2"')
    short = short.replace("seeds = [0, 1]", "seeds = [0]").replace("epochs = 3,", "epochs = 1,")
    short = "\n".join(line for line in short.splitlines() if not line.startswith("phase2")) + "\n"
    long = long.replace("seeds = [0, 1]", "seeds = [0]").replace("epochs = 2,", "epochs = 5000,", 1)
    spec.write_text(short + '\n[[row]]\nname = "he-k2"' + long)
    rows = tmp_path / "rows.jsonl"
    process = subprocess.Popen(mjx_emp("sweep", str(spec), "--runs", str(tmp_path / "runs"), "--results", str(rows),
                                       "--workers", "2"),
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 400
    while not (rows.exists() and read_rows(rows)):
        assert process.poll() is None and time.monotonic() < deadline, "the sweep ended before its first row"
        time.sleep(0.1)
    process.send_signal(signal.SIGTERM)
    try:
        _, stderr = process.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        pytest.fail("the sweep did not end within 120 s of SIGTERM")
    assert process.returncode == 128 + signal.SIGTERM, stderr[-3000:]
    assert stderr.startswith("mjx-emp: sweep smoke-point-mass stopped by SIGTERM with 1 of 2 runs evaluated"), stderr
    assert [row["row"] for row in read_rows(rows)] == ["he-k1"]
    worker_log = (tmp_path / "runs" / "smoke-point-mass" / "logs" / "he-k2.log").read_text()
    assert "stopped by SIGTERM; the newest checkpoint is epoch" in worker_log, worker_log[-2000:]


def test_a_row_with_skills_from_builds_its_phase_2_on_a_copy_of_the_other_rows_runs(swept, tmp_path):
    """A phase-2 variant on the smoke spec's he-k1 skills: the spec with one more row that names
    he-k1 as its skills, swept again in-process into the same runs and store. Only the new row is
    done: seed 1's phase 1 copied (not trained), a phase 2 with the row's own overrides, one row
    whose training figures are he-k1's and whose phase 2 is its own."""
    import shutil

    from mjx_emp.run.sweep import sweep as run_sweep

    spec = tmp_path / "smoke-point-mass.toml"
    spec.write_text(SMOKE.read_text() + '\n[[row]]\nname = "he-k1-p2-flip-cost"\nskills_from = "he-k1"\nseeds = [1]\n'
                    'phase2 = "auto"\nphase2_overrides = { epochs = 2, num_envs = 8, hidden = [32], batch_size = 32, '
                    'grad_steps = 5, iterations = 2, replay_capacity = 2048, flip_cost = 5.0 }\n')
    results = tmp_path / "rows.jsonl"
    shutil.copy(swept / "rows.jsonl", results)
    source = swept / "runs" / "smoke-point-mass" / "he-k1-s1"
    metrics_before = (source / "metrics.jsonl").stat().st_mtime_ns
    written = run_sweep(str(spec), runs=str(swept / "runs"), results=str(results), report=lambda line: None)
    (row,) = written
    assert row["row"] == "he-k1-p2-flip-cost" and row["seed"] == 1
    assert row["evaluation"]["did"][0] == "copied phase 1 of seed 1 from row he-k1"
    assert row["phase2_config"]["flip_cost"] == 5.0
    (source_row,) = [r for r in read_rows(results) if (r["row"], r["seed"]) == ("he-k1", 1)]
    assert row["curves"]["env_steps"] == source_row["curves"]["env_steps"]
    assert row["figures"]["levels"] == source_row["figures"]["levels"]  # the same skills, evaluated alike
    assert row["train"]["config"] == source_row["train"]["config"]
    assert (source / "metrics.jsonl").stat().st_mtime_ns == metrics_before  # the source run is left alone
    assert not (source.parent / "he-k1-p2-flip-cost-s1.partial").exists()
    assert run_sweep(str(spec), runs=str(swept / "runs"), results=str(results), report=lambda line: None) == []


def test_jobs_run_in_spec_order_and_a_skills_from_row_after_its_source():
    """One worker: each job as the one before ends, a variant of a row's skills right after that
    row (not after the rows between); two workers: two at a time, the variant waiting for its
    source however long the other row takes."""
    import concurrent.futures

    from mjx_emp.run.sweep import Job, schedule

    spec = load_spec(SMOKE)
    source, other = spec.rows
    variant = dataclasses.replace(source, name="variant", skills_from=source.name)
    jobs = [Job("s", row, "base", (), (), 1, "log", "cmd", None if row.skills_from is None else "base")
            for row in (source, other, variant)]

    def run(limit, slow):
        started, running_at_start = [], []
        live: dict = {}

        def submit(job):
            started.append(job.row.name)
            running_at_start.append(sorted(j.row.name for j in live.values()))
            future = concurrent.futures.Future()
            live[future] = job
            return future

        def next_done(running):  # the jobs end in submission order, the slow one last
            future = min(running, key=lambda f: (live[f].row.name == slow, list(live).index(f)))
            future.set_result([])
            del live[future]
            return future

        ended = [job.row.name for job, _ in schedule(jobs, limit, submit, next_done)]
        return started, running_at_start, ended

    assert run(1, slow="")[0] == ["he-k1", "he-k2", "variant"]
    started, running_at_start, ended = run(2, slow="he-k1")
    assert started == ["he-k1", "he-k2", "variant"] and ended == ["he-k2", "he-k1", "variant"]
    assert running_at_start[2] == []  # the variant started once its source had ended
    # A source row with nothing left to do has no job: its variant is ready at once.
    assert [job.row.name for job, _ in schedule(jobs[2:], 1, lambda job: concurrent.futures.Future(),
                                                  lambda running: [f.set_result([]) or f for f in running][0])] \
        == ["variant"]


SPEC_HEAD = 'name = "bad"\n'
GOOD_ROW = '[[row]]\nname = "a"\npreset = "point-mass-k1"\nseeds = [0]\n'


@pytest.mark.parametrize("body, named", [
    ('[[row]]\nname = "a"\npreset = "point-mass-k9"\nseeds = [0]\n', ["row 'a'", "preset", "point-mass-k1"]),
    (GOOD_ROW + 'overrides = { epoch = 3 }\n', ["row 'a'", "overrides.epoch", "not a field"]),
    (GOOD_ROW + 'colour = "red"\n', ["row 'a'", "colour", "not a row field"]),
    (GOOD_ROW + 'overrides = { epochs = "three" }\n', ["row 'a'", "overrides.epochs", "must be int"]),
    (GOOD_ROW + 'overrides = { epochs = 0 }\n', ["row 'a'", "epochs"]),
    ('[[row]]\nname = "a"\npreset = "point-mass-k1"\nseeds = [0.5]\n', ["row 'a'", "seeds", "integer"]),
    (GOOD_ROW + GOOD_ROW, ["row 'a'", "name", "given twice"]),
    (GOOD_ROW + GOOD_ROW.replace('"a"', '"b"'), ["row 'b'", "duplicate row", "row 'a'"]),
    ('[[row]]\nname = "a"\npreset = "point-mass-k1"\nseeds = []\n', ["row 'a'", "seeds", "non-empty"]),
    (GOOD_ROW + 'phase2 = "reach-the-moon"\n', ["row 'a'", "phase2", "not a phase-2 preset"]),
    (GOOD_ROW + 'phase2 = "auto"\nphase2_overrides = { eps = -1.0 }\n', ["row 'a'", "phase2_overrides", "eps"]),
    ('coverage_draws = 1001\n' + GOOD_ROW, ["coverage_draws", "[1, 1000]"]),
    ('[report]\nreps = 0\n' + GOOD_ROW, ["report.reps", ">= 1"]),
    ('[report]\nrows = "he-*"\n' + GOOD_ROW, ["report.rows", "list"]),
    (GOOD_ROW + '[[row]]\nname = "b"\nskills_from = "c"\nphase2 = "auto"\n', ["row 'b'", "skills_from", "'c'"]),
    (GOOD_ROW + '[[row]]\nname = "b"\nskills_from = "a"\npreset = "point-mass-k2"\nphase2 = "auto"\n',
     ["row 'b'", "preset", "takes its phase 1 from row 'a'"]),
    (GOOD_ROW + '[[row]]\nname = "b"\nskills_from = "a"\nseeds = [3]\nphase2 = "auto"\n', ["row 'b'", "seeds"]),
    (GOOD_ROW + '[[row]]\nname = "b"\nskills_from = "a"\n', ["row 'b'", "phase2", "needs a phase 2"]),
    (GOOD_ROW + '[[row]]\nname = "b"\nskills_from = 1\nphase2 = "auto"\n', ["row 'b'", "skills_from", "name"]),
    (GOOD_ROW + '[[row]]\nname = "b"\nskills_from = "a"\nseeds = [[0]]\nphase2 = "auto"\n', ["row 'b'", "seeds"]),
])
def test_a_bad_spec_is_refused_naming_the_row_and_the_field(tmp_path, body, named):
    path = tmp_path / "bad.toml"
    path.write_text(SPEC_HEAD + body)
    with pytest.raises(ConfigError) as refused:
        load_spec(path)
    for part in named:
        assert part in str(refused.value), (part, str(refused.value))


def test_a_benchmark_specs_report_table_is_checked_as_a_sweeps_is(tmp_path):
    from mjx_emp.report import load_report_spec

    path = tmp_path / "bench.toml"
    path.write_text('name = "bench-x"\ncommand = "python benchmarks/x.py"\n[report]\nreps = "many"\n')
    with pytest.raises(ConfigError, match="report.reps"):
        load_report_spec(str(path))
    path.write_text('name = "bench-x"\ncommand = "python benchmarks/x.py"\n[report]\nrows = ["a/*"]\n')
    assert load_report_spec(str(path)).report == {"rows": ["a/*"]}


def test_the_cli_refuses_a_bad_spec_with_exit_2_before_anything_trains(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(SPEC_HEAD + GOOD_ROW + 'overrides = { epochs = "three" }\n')
    result = run_cli("sweep", str(path), "--runs", str(tmp_path / "runs"))
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1].startswith("mjx-emp: invalid configuration: row 'a': overrides.epochs")
    assert not (tmp_path / "runs").exists()


def test_a_failed_job_is_one_error_naming_its_row_and_log():
    import concurrent.futures

    from mjx_emp.errors import JobFailed
    from mjx_emp.run.sweep import Job, job_rows

    spec = load_spec(SMOKE)
    job = Job(spec.name, spec.rows[0], "r", ("r-s0", "r-s1"), (0, 0), 1, "runs/x/logs/he-k1.log", "mjx-emp sweep")
    failed = concurrent.futures.Future()
    failed.set_exception(FloatingPointError("a diverged critic"))
    with pytest.raises(JobFailed, match="row 'he-k1' failed .*a diverged critic.*runs/x/logs/he-k1.log"):
        job_rows(job, failed)


def test_a_phase_2_differing_only_in_when_it_stops_is_the_rows_and_any_other_change_is_not():
    from mjx_emp.phase2.presets import PHASE2_PRESETS
    from mjx_emp.run.sweep import same_phase2

    wanted = PHASE2_PRESETS["reach-ant-field-cpu"][2]
    held = dataclasses.replace(wanted, phase1_epoch=140, epochs=wanted.epochs + 10, max_env_steps=10_000)
    assert same_phase2(held, wanted)
    assert not same_phase2(dataclasses.replace(held, n=wanted.n + 1), wanted)
    assert not same_phase2(dataclasses.replace(held, flip_cost=10.0), wanted)
