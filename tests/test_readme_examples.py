"""The README's five-minute tour (issue 26, items 12 and 14): every fenced `sh` command of its
"A five-minute tour" section runs, as printed, in an empty directory and writes what the README
shows. The set-up block above the tour (`make paper`, `make test`) is not run here: it is the
whole reproduction and the suite itself, which CI runs on a clean clone (`.ci/run`)."""
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import haa_sym

from conftest import ROOT


def tour_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    section = text.split("## A five-minute tour", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```sh\n(.*?)```", section, re.S)
    return [ln.strip() for b in blocks for ln in b.replace("\\\n", " ").splitlines() if ln.strip()]


def test_the_tour_is_three_commands_each_with_its_picture():
    cmds = tour_commands()
    assert len(cmds) == 3 and all(c.startswith("haa-sym ") for c in cmds)
    section = (ROOT / "README.md").read_text().split("## A five-minute tour", 1)[1].split("\n## ", 1)[0]
    pictures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", section)
    assert len(pictures) == 3 and all((ROOT / p).stat().st_size > 10_000 for p in pictures)


def test_the_readme_links_only_to_pages_that_exist():
    links = re.findall(r"\]\((docs/[^)#]*)", (ROOT / "README.md").read_text())
    assert len(links) >= 10
    missing = [p for p in links if not (ROOT / p).exists()]
    assert missing == []


@pytest.mark.slow                     # the three commands, about 15 s (the schedule 12 s)
def test_the_tour_runs_as_printed(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(Path(haa_sym.__file__).parents[1])] + [p for p in [os.environ.get("PYTHONPATH")] if p])}
    for cmd in tour_commands():
        argv = [sys.executable, "-m", "haa_sym.cli"] + shlex.split(cmd)[1:]
        proc = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, (cmd, proc.stderr[-2000:])
        assert "Traceback" not in proc.stderr, cmd
        # every file the command names (--out, --plot, --c-out) is written, and is not empty
        words = shlex.split(cmd)
        for flag in ("--out", "--plot", "--c-out"):
            if flag in words:
                out = tmp_path / words[words.index(flag) + 1]
                assert out.exists(), (cmd, flag)
                if out.is_file():
                    assert out.stat().st_size > 100, (cmd, flag)
    assert sorted(p.name for p in (tmp_path / "ctrl").iterdir()) == ["haa_schedule.c", "haa_schedule.h"]
    assert (tmp_path / "schedule.csv").read_text().startswith("P_gain,D_gain,beta,")
