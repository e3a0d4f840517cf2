"""The documentation site (issue 26, item 14): its pages are all in the toctree of docs/index.md,
the build is `make docs` with warnings as errors, the benchmark tables live on a page of their own
and the renderer writes there, and the README stays a short guide."""
import json
import re
import sys

from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
import render_readme  # noqa: E402


def test_every_page_is_in_the_index():
    index = (ROOT / "docs" / "index.md").read_text()
    listed = set(re.findall(r"^([a-z][a-z-]*)$", index, re.M))
    pages = {p.stem for p in (ROOT / "docs").glob("*.md")} - {"index"}
    assert pages == listed


def test_make_docs_builds_with_warnings_as_errors_and_ci_runs_it():
    make = (ROOT / "Makefile").read_text()
    rule = make.split("\ndocs: $(STAMP)\n", 1)[1].split("\n\n", 1)[0]
    assert "sphinx -W --keep-going" in rule and "docs docs/_build/html" in rule
    assert "'.[test,docs]'" in make                      # the venv gets the docs extra
    assert re.search(r"^make docs$", (ROOT / ".ci" / "run").read_text(), re.M)
    assert "docs/_build/" in (ROOT / ".gitignore").read_text().splitlines()


def test_the_benchmark_block_is_on_its_page_and_the_renderer_writes_there(tmp_path):
    page = (ROOT / "docs" / "benchmarks.md").read_text()
    assert page.count(render_readme.START) == 1 and page.count(render_readme.END) == 1
    assert render_readme.START not in (ROOT / "README.md").read_text()
    # the renderer's default target is the page; a missing JSON directory renders "not measured"
    # cells and leaves the text outside the markers as it was
    copy = tmp_path / "benchmarks.md"
    copy.write_text(page)
    assert render_readme.main(["--results", str(tmp_path / "none"), "--page", str(copy)]) == 0
    new = copy.read_text()
    before, after = page.split(render_readme.START)[0], page.split(render_readme.END)[1]
    assert new.startswith(before) and new.endswith(after) and "not measured" in new
    assert render_readme.main(["--results", str(tmp_path / "none"), "--page", str(copy), "--check"]) == 0


def test_the_readme_is_short():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) < 100
    assert "pip install 'haa_sym[" not in readme         # not on an index: the extras from a checkout
    assert "pip install -e '.[explore]'" in readme


def test_the_scale_block_is_rendered_from_bench_scales_json_and_kept_without_it(tmp_path):
    # issue 27: local:1 against local:2, whole command, from benchmarks/bench_scale.py --whole
    page = (ROOT / "docs" / "benchmarks.md").read_text()
    assert page.count(render_readme.SCALE_START) == 1 and page.count(render_readme.SCALE_END) == 1
    copy = tmp_path / "benchmarks.md"
    copy.write_text(page)
    results = tmp_path / "results"
    results.mkdir()
    runs = [{"round": r, "workers": n, "seconds": s, "cores_available_before": 1.9, "load_1min_before": 0.5,
             "same_output": True} for r, (n, s) in enumerate([(1, 12.0), (2, 6.5), (1, 11.0), (2, 6.6)])]
    whole = {"runs": runs, "same_output": True, "best_s": {"1": 11.0, "2": 6.5}, "median_s": {"1": 11.5, "2": 6.55},
             "speedup_of_best": {"2": 11.0 / 6.5}, "speedup_per_round": {"2": [12.0 / 6.5, 11.0 / 6.6]},
             "copies_speedup_per_round": [1.90, 1.70], "cores_available_before": [1.9] * 4,
             "fixed_s": 0.9, "predicted_s": {"16": 3.3}, "task_lists_speedup_per_round": {"2": [1.95, 1.90]}}
    data = {"run": {"date": "2026-11-26T17:00:00+00:00"}, "rows": [{"seconds": 30.0}], "same_output": True,
            "serial_s": 0.5, "longest_chain_s": 0.6, "work_s": 29.0, "predicted_s": {"16": 2.4},
            "whole_command": whole}
    (results / "results_scale_schedule.json").write_text(json.dumps(data))
    assert render_readme.main(["--results", str(results), "--page", str(copy), "--scale-only"]) == 0
    new = copy.read_text()
    block = new.split(render_readme.SCALE_START)[1].split(render_readme.SCALE_END)[0]
    row = next(line for line in block.splitlines() if line.startswith("| `schedule`"))
    assert "11.0 s (median 11.5 s)" in row and "**1.69x** best / best; the target met in 1 of 2 rounds / 1.85x, 1.67x" in row
    # and each round's speedup of the task lists' span alone (without the fixed part)
    assert "1.85x, 1.67x; the task lists' span alone 1.95x, 1.90x |" in row
    # the two copies' speedup each round (the reference), and the speedup's share of it (12 / 6.5 / 1.9 = 0.97, 11 / 6.6 / 1.7 = 0.98)
    assert "| 1.90x, 1.70x (0.97, 0.98) |" in row
    assert "2.40 s on 16, 12.5x the 1-worker run" in row
    # and the whole command's: F + the warm prediction, against the best whole local:1 (11.0 / 3.3)
    assert "whole command F 0.90 s + that: 3.30 s, 3.3x the whole `local:1`" in row
    # and with what 16 workers' start and stop cost the command's process more than one's
    whole.update(cluster_more_s={"16": 0.18}, predicted_s={"16": 3.48})
    (results / "results_scale_schedule.json").write_text(json.dumps(data))
    assert render_readme.main(["--results", str(results), "--page", str(copy), "--scale-only"]) == 0
    row = next(line for line in copy.read_text().split(render_readme.SCALE_START)[1].splitlines()
               if line.startswith("| `schedule`"))
    assert "whole command F 0.90 s + 16 workers' start and stop 0.18 s + that: 3.48 s, 3.2x the whole" in row
    assert "| `regions --nonlinear`" in block and "not measured" in block
    # the other block and the text around are the page's
    assert new.split(render_readme.SCALE_START)[0] == page.split(render_readme.SCALE_START)[0]
    assert new.split(render_readme.SCALE_END)[1] == page.split(render_readme.SCALE_END)[1]
    # without bench_scale.py's JSON (make bench-readme after make bench) the block stays
    assert render_readme.main(["--results", str(tmp_path / "none"), "--page", str(copy)]) == 0
    assert copy.read_text().count(row) == 1


def test_every_column_of_the_schedule_csv_is_documented():
    """docs/schedule.md's table of the CSV has a row for each column haa-sym schedule --out writes,
    in the order written, and no other."""
    from haa_sym.design.schedule import CSV_COLUMNS
    page = (ROOT / "docs" / "schedule.md").read_text()
    section = page.split("## The CSV (`--out`)", 1)[1].split("\n## ", 1)[0]
    assert tuple(re.findall(r"^\| `(\w+)` \|", section, re.M)) == CSV_COLUMNS
