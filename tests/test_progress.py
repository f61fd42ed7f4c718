"""Progress on the terminal (issue 14): a "starting" line when each stage begins and its
time when it ends (terminal or not), progress bars with an ETA on stderr only when it is
a terminal, and nothing at all in quiet mode."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from prtcore.cli import main
from prtcore.core import progress
from prtcore.core.progress import StageTimer

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "examples" / "cornell_box.glb"
#: a bake of about a second
SMALL_SPEC = {
    "atlas": {"resolution": 32, "padding": 2},
    "measurement_points": {"count": 24, "supersample": 1},
    "lights": {"count": 16, "holdout": 2, "families": [
        {"type": "point", "position": {"box": [[-0.5, 0.5, -0.5], [0.5, 1.5, 0.5]]}}]},
    "transport": {"gather_rays": 8, "max_bounces": 4},
    "fit": {"basis": 4},
}
LINE = re.compile(r"^\[prtcore\] (.+?)\s+(starting|\d+\.\d\d s|skipped: .*)$")


@pytest.fixture
def tty(monkeypatch):
    """stderr reports itself as a terminal (whichever stream capsys has installed by the
    time the timer asks)."""
    monkeypatch.setattr(progress, "_stderr_is_tty", lambda: True)


def _events(err: str) -> list[tuple[str, str]]:
    """(stage, "starting" | "end" | "skipped") for each stage line, in order; the lines
    may share a physical line with bar redraws (carriage returns)."""
    out = []
    for raw in err.splitlines():
        m = LINE.match(raw.split("\r")[-1].strip())
        if m:
            kind = m.group(2)
            out.append((m.group(1), "starting" if kind == "starting" else
                        "skipped" if kind.startswith("skipped") else "end"))
    return out


def _check_every_stage_starts_before_it_ends(events: list[tuple[str, str]]) -> None:
    open_stage = None
    ended = []
    for name, kind in events:
        if kind == "starting":
            assert open_stage is None, f"{name} starts inside {open_stage}: {events}"
            open_stage = name
        elif kind == "end":
            assert open_stage == name, f"{name} ends without starting: {events}"
            open_stage = None
            ended.append(name)
    assert open_stage is None and ended


def test_stage_prints_starting_then_its_time(capsys, tty):
    timer = StageTimer()
    with timer.stage("gather operator"):
        assert capsys.readouterr().err == "[prtcore] gather operator    starting\n"
        time.sleep(0.01)
    err = capsys.readouterr().err
    assert re.fullmatch(r"\[prtcore\] gather operator\s+\d+\.\d\d s\n", err), err
    timer.skip("repair", "mesh clean")
    assert "skipped: mesh clean" in capsys.readouterr().err


def test_bar_with_eta_on_a_terminal(capsys, monkeypatch):
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # capsys's stream, now
    timer = StageTimer()
    with timer.stage("direct texels"):
        for _ in timer.bar(range(8), "direct texels"):
            time.sleep(0.06)
    err = capsys.readouterr().err
    lines = err.split("\n")
    assert lines[0] == "[prtcore] direct texels      starting"
    # tqdm redraws with \r: counts, elapsed < remaining (the ETA), rate
    assert re.search(r"direct texels:\s+\d+%\|.*\| [1-8]/8 \[00:00<00:0\d, ", err), err
    assert re.search(r"\[prtcore\] direct texels\s+0\.\d\d s\n$", err), err


def test_no_bar_when_stderr_is_not_a_terminal(capsys):
    timer = StageTimer()
    with timer.stage("gather operator"):
        for _ in timer.bar(range(3), "gather", total=3):
            pass
    err = capsys.readouterr().err
    assert "\r" not in err and "it/s" not in err
    assert [ln.split()[-1] for ln in err.splitlines()] == ["starting", "s"]


def test_quiet_prints_nothing(capsys, tty):
    timer = StageTimer(quiet=True)
    with timer.stage("gather operator"):
        for _ in timer.bar(range(3), "gather", total=3):
            time.sleep(0.01)
        for _ in progress.bar(range(3), "report"):
            pass
    timer.skip("repair", "mesh clean")
    assert capsys.readouterr() == ("", "")
    assert timer.seconds["gather operator"] > 0


def test_module_bar_uses_the_running_stage(capsys, tty):
    """Loops whose caller passes no timer (the report's table) draw on the timer of the
    stage running; outside a stage the iterable is returned unchanged."""
    it = range(3)
    assert progress.bar(it, "x") is it
    timer = StageTimer()
    with timer.stage("report"):
        assert list(progress.bar(range(3), "error vs run time")) == [0, 1, 2]
    assert "error vs run time:" in capsys.readouterr().err
    assert progress.bar(it, "x") is it


def test_zero_size_terminal_gets_a_visible_bar(monkeypatch):
    """`script` and `docker run -t` report 0 × 0 until the first resize; tqdm then draws
    nothing (0 columns) and hides every bar (0 lines). The bars fall back to 80 × 24."""
    for env in ("COLUMNS", "LINES"):
        monkeypatch.delenv(env, raising=False)
    monkeypatch.setattr(os, "get_terminal_size", lambda fd=0: os.terminal_size((0, 0)))
    assert progress._terminal_size() == progress.FALLBACK_SIZE == (80, 24)
    monkeypatch.setattr(os, "get_terminal_size", lambda fd=0: os.terminal_size((132, 40)))
    assert progress._terminal_size() == (132, 40)
    monkeypatch.setenv("COLUMNS", "100")
    assert progress._terminal_size() == (100, 40)


def test_bake_on_a_terminal_and_quiet(tmp_path, capsys, tty):
    """`prtcore bake` on a terminal: every stage prints "starting" before its time, and
    bars are drawn; with -q nothing reaches stderr."""
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(SMALL_SPEC))
    # a small bake whose verdict may fail: --allow-poor (this test is about progress)
    assert main(["bake", str(CORNELL), "--spec", str(spec), "--out",
                 str(tmp_path / "a"), "--allow-poor"]) == 0
    err = capsys.readouterr().err
    events = _events(err)
    _check_every_stage_starts_before_it_ends(events)
    ended = [n for n, k in events if k == "end"]
    for stage in ("load", "texels", "points", "lights", "gather operator", "direct texels",
                  "indirect solve", "fit", "report", "export"):
        assert stage in ended, (stage, events)
    assert "gather:" in err and "it/s" in err  # the transport's bars
    assert main(["bake", str(CORNELL), "--spec", str(spec), "--out", str(tmp_path / "b"),
                 "-q", "--allow-poor"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert "bake stages" not in out  # -q: no stage timings (the table is not printed)


@pytest.mark.skipif(shutil.which("script") is None, reason="needs util-linux `script`")
def test_bake_under_a_real_terminal(tmp_path):
    """The CLI under a pseudo-terminal (`script`, which reports 0 columns): a "starting"
    line before each stage's end line and visible bars; -q prints nothing."""
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(SMALL_SPEC))

    def run(*extra: str) -> str:
        log = tmp_path / "typescript"
        cmd = " ".join([sys.executable, "-m", "prtcore", "bake", str(CORNELL), "--spec",
                        str(spec), "--out", str(tmp_path / "out"), "--force",
                        "--allow-poor", *extra,
                        "2>&1 >/dev/null"])  # stderr only, onto the terminal
        env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
        r = subprocess.run(["script", "-qec", cmd, str(log)], cwd=ROOT, timeout=600,
                           capture_output=True, text=True, env={**env, "TERM": "xterm"})
        assert r.returncode == 0, (r.stdout, r.stderr, log.read_text())
        lines = log.read_text(errors="replace").replace("\r\n", "\n").split("\n")
        return "\n".join(ln for ln in lines  # without script's own header and footer
                         if not ln.startswith(("Script started", "Script done")))

    err = run()
    _check_every_stage_starts_before_it_ends(_events(err))
    assert re.search(r"gather:\s+\d+%\|", err), err  # a bar was drawn, not an empty line
    assert run("-q").strip() == ""
