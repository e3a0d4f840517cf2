"""The documentation site (issue 26, item 14): its pages are all in the toctree of docs/index.md,
the build is `make docs` with warnings as errors, the benchmark tables live on a page of their own
and the renderer writes there, and the README stays a short guide."""
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
