"""The benchmark scripts' rows: named as the rows carried over from their former result files were
(so that a new measurement replaces the stored one), and appended with the script's figures."""

import json
from pathlib import Path

import pytest
from tiny import benchmark

from mjx_emp.run.rows import read_rows

ROOT = Path(__file__).resolve().parents[1]
bench_rows = benchmark("bench_rows")


def carried(spec: str) -> list[dict]:
    """The committed rows of ``spec``, each record as its script measured it (the carry's additions left out)."""
    rows = [json.loads(line) for line in (ROOT / "results" / f"{spec}.jsonl").read_text().splitlines()]
    for row in rows:
        row["record"] = {k: v for k, v in row["figures"].items() if k not in ("source_group", "file_fields")}
    return rows


@pytest.mark.parametrize("spec", ["bench-rollout", "bench-rollout-solver", "bench-train", "bench-seeds", "bench-scaling",
                                  "bench-paper-shapes", "bench-compile-cache", "bench-time-to-quality",
                                  "bench-sweep-overhead"])
def test_a_benchmark_names_each_setting_as_its_carried_row(spec):
    names = bench_rows.RowNames()
    for row in carried(spec):
        group = row["figures"]["source_group"]
        group = "" if group.endswith("_cpu") else group  # the file's own records: no group
        assert names(row["record"], group, row["seed"]) == row["row"]


def test_the_gpu_leases_rows_are_named_as_the_check_and_the_summary_name_them():
    names = bench_rows.RowNames()
    for row in carried("gpu-leases"):
        lease = row["row"].split("/")[0]
        assert names(row["record"], f"{lease}/{row['figures']['source_group']}") == row["row"]
    assert bench_rows.lease_name("NVIDIA H200") == "gpu_lease_h200"


def test_flag_sets_and_robots_keep_their_carried_names_whichever_a_run_measures():
    by_flags = {row["figures"]["flags"]: row["row"] for row in carried("bench-compile-flags")}
    assert {name: benchmark("compile_flags").ROW_NAMES[name] for name in by_flags} == by_flags
    by_robot = {row["figures"]["robot"]: row["row"] for row in carried("bench-robot-models")}
    assert {robot: benchmark("robots").ROW_NAMES[robot] for robot in by_robot} == by_robot


def test_compile_flags_appends_one_row_per_flag_set_it_times(tmp_path, monkeypatch):
    flags = benchmark("compile_flags")
    timing = {"total_s": 2.0, "trace_s": 0.5, "lower_s": 0.25, "backend_compile_s": 1.0, "backend": "cpu"}
    monkeypatch.setattr(flags, "time_once", lambda _: dict(timing))
    results = tmp_path / "rows.jsonl"
    flags.main(flags.Args(sets=("llvm-O0",), rounds=2, results=str(results), beside="a test"))
    (row,) = read_rows(results)
    assert (row["spec"], row["row"], row["seed"], row["kind"]) == ("bench-compile-flags", "all#2", 0, "benchmark")
    assert row["figures"]["backend_compile_s"] == 1.0 and row["figures"]["backend_compile_s_each"] == [1.0, 1.0]
    assert row["figures"]["beside"] == "a test" and row["train"]["commit"]  # with this process's provenance
