"""The repository as a user meets it: a README of at most 120 lines, no reference to a file outside
the repository, and every command's ``--help`` giving each option in at most two lines."""

import importlib
import re
import runpy
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: What points outside the repository: the workspace's shared folder and absolute machine paths.
OUTSIDE = re.compile(r"\.\./shared|\bshared/(paper|reference|tools)\b|/work/")
TEXT = {".py", ".md", ".toml", ".txt", ".cfg", ".json", ".yml", ".yaml", ".sh", ".tex"}
SKIPPED = {".git", ".venv", "__pycache__", ".pytest_cache", "ncedf.egg-info"}
MODULES = ["scenarios.cluttered", "scenarios.spheres", "scenarios.charging", "scenarios.window", "scenarios.cabinet",
           "scenarios.pipe", "scenarios.slot", "scenarios.pillars", "scenarios.custom", "scenarios.sweep",
           "scenarios.floor", "scenarios.reproduce", "ncedf.train", "ncedf.evaluate", "analysis.make_tables",
           "analysis.make_figures", "recorder.inspect", "recorder.synthetic"]
SCRIPTS = sorted(p for p in [*(ROOT / "bench").glob("*.py"), ROOT / "analysis" / "bench_read.py"]
                 if '__name__ == "__main__"' in p.read_text())


def repository_files():
    for path in ROOT.rglob("*"):
        if path.is_file() and not SKIPPED & set(path.relative_to(ROOT).parts) and (path.suffix in TEXT or
                                                                                  path.parent.name == ".ci"):
            yield path


def test_the_readme_is_a_short_guide():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 120


def test_nothing_refers_to_a_file_outside_the_repository():
    found = [f"{path.relative_to(ROOT)}:{n}: {line.strip()}" for path in repository_files()
             for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1)
             if OUTSIDE.search(line) and path != Path(__file__).resolve()]
    assert not found, "\n".join(found)


def option_entries(help_text: str) -> list[list[str]]:
    """The lines of each option's entry in an argparse help text (its flags' line and what follows,
    indented deeper)."""
    entries, current = [], None
    for line in help_text.splitlines():
        if re.match(r"^  -", line):
            current = [line]
            entries.append(current)
        elif current is not None and line.startswith("   "):
            current.append(line)
        else:
            current = None
    return entries


def help_of(run, capsys) -> str:
    with pytest.raises(SystemExit) as stop:
        run()
    assert stop.value.code == 0
    return capsys.readouterr().out


def long_entries(text: str) -> list[str]:
    return [entry[0].strip() for entry in option_entries(text) if len(entry) > 2]


@pytest.mark.parametrize("module", MODULES)
def test_every_option_of_a_command_is_at_most_two_lines(module, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    text = help_of(lambda: importlib.import_module(module).main(["--help"]), capsys)
    assert option_entries(text) and not long_entries(text)


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_every_option_of_a_benchmark_is_at_most_two_lines(script, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    monkeypatch.setattr(sys, "argv", [str(script), "--help"])
    monkeypatch.syspath_prepend(str(script.parent))
    text = help_of(lambda: runpy.run_path(str(script), run_name="__main__"), capsys)
    assert option_entries(text) and not long_entries(text)


def one_line_error(run, capsys) -> str:
    with pytest.raises(SystemExit) as stop:
        run()
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "usage:" not in err, err
    return err


@pytest.mark.parametrize("module", MODULES)
def test_an_unknown_option_is_a_one_line_error(module, capsys):
    err = one_line_error(lambda: importlib.import_module(module).main(["--no-such-option"]), capsys)
    assert ": error: " in err


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_an_unknown_option_of_a_benchmark_is_a_one_line_error(script, capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", [str(script), "--no-such-option"])
    monkeypatch.syspath_prepend(str(script.parent))
    err = one_line_error(lambda: runpy.run_path(str(script), run_name="__main__"), capsys)
    assert ": error: " in err


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_benchmark_stopped_by_a_signal_says_so_in_one_line(sig, capsys, monkeypatch):
    """``recorder.cli.stoppable``, the stop of the benchmarks' ``__main__``: a signal in the middle of the
    work ends it with one line and the signal's exit status, and no traceback."""
    import os
    import signal
    import time

    from recorder.cli import stoppable

    def work():
        print("row 1", flush=True)
        os.kill(os.getpid(), getattr(signal, sig))
        time.sleep(5)
        print("row 2")

    assert stoppable(work) == 128 + getattr(signal, sig)
    out = capsys.readouterr()
    assert out.out == "row 1\n" and out.err == f"interrupted ({sig}): the rows above are complete\n"


@pytest.mark.parametrize("module, argv", [
    ("scenarios.cluttered", ["--out", ""]), ("scenarios.sweep", ["--scenario", "cluttered", "--out", ""]),
    ("scenarios.reproduce", ["table1", "--quick", "--out", ""]), ("ncedf.train", ["--out", " "]),
    ("analysis.make_tables", ["--out", ""]), ("recorder.synthetic", [""]), ("scenarios.floor", [""]),
])
def test_an_empty_path_is_a_one_line_error_and_nothing_is_written(module, argv, capsys, tmp_path, monkeypatch):
    """The empty string names no file stem, and as a folder the current one: refused before any work."""
    monkeypatch.chdir(tmp_path)
    err = one_line_error(lambda: importlib.import_module(module).main(argv), capsys)
    assert "must name a path" in err and not list(tmp_path.iterdir())
