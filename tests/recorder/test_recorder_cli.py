"""The shared command-line conventions (``recorder.cli``): a signal that interrupts an XLA compilation
still ends the command with its one line and exit status 130, not a crash in the interpreter's teardown;
warnings on one line, those asked for once per text."""

import subprocess
import sys
import textwrap
import warnings

import pytest

from recorder.cli import one_line_warnings

#: A command that compiles a long chain of operations (seconds) and sends itself SIGINT 0.5 s into it.
SCRIPT = textwrap.dedent("""
    import os, signal, sys, threading
    import jax, jax.numpy as jnp
    from recorder.cli import EXIT_STATUS, Stopped, {end}, stop_on_signals

    def chain(x):
        for i in range(1500):
            x = jnp.sin(x * (i + 1.0)) + jnp.cos(x[::-1])
        return x

    def main():
        lowered = jax.jit(chain).lower(jnp.ones(64))
        try:
            with stop_on_signals():
                threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT)).start()
                lowered.compile()
                print("compiled before the signal")
                return 0
        except Stopped as stop:
            print(f"stopped by {{stop}}", file=sys.stderr)
            return EXIT_STATUS[stop.signum]

    {end}(main())
""")


def run(end: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", SCRIPT.format(end=end)], capture_output=True, text=True,
                          timeout=300)


def test_a_signal_during_compilation_exits_with_its_status():
    done = run("exit_with")
    assert "compiled" not in done.stdout  # the signal came during the compilation
    assert done.returncode == 130, done.stderr
    assert done.stderr == "stopped by SIGINT\n"


@pytest.mark.parametrize("status", [0, 2])
def test_other_statuses_exit_normally(status):
    code = ("import atexit\nfrom recorder.cli import exit_with\n"
            f"atexit.register(print, 'teardown ran')\nexit_with({status})")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == status and done.stdout == "teardown ran\n"


def test_warnings_show_on_one_line_and_a_text_asked_for_once_comes_once(capsys):
    def warn(text):  # one place that warns ...
        warnings.warn(UserWarning(text))

    with one_line_warnings(once=(UserWarning,)):
        warn("open mesh")
        with warnings.catch_warnings():  # a change of the filters between: the filters' "once" forgets
            warnings.simplefilter("ignore", DeprecationWarning)
        warnings.warn(UserWarning("open mesh"))  # ... and another: the same text
        warn("another mesh")
        warnings.warn(RuntimeWarning("open mesh"))  # not asked for once
    assert capsys.readouterr().err.splitlines() == ["warning: open mesh", "warning: another mesh",
                                                    "warning: open mesh"]
