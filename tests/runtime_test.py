"""CLI process set-up: the malloc tunables for training only, with an opt-out."""

import importlib
import os
import subprocess
import sys

import pytest

from rpmnet_jax.cli import runtime


@pytest.mark.parametrize("module, tuned", [("register", False), ("evaluate", False), ("eval_scans", False),
                                           ("train", True)])
def test_only_training_asks_for_the_malloc_tunables(monkeypatch, module, tuned):
    calls = []
    monkeypatch.setattr(runtime, "use_huge_pages", lambda: calls.append(module))
    monkeypatch.setattr(runtime, "enable_compilation_cache", lambda: None)
    monkeypatch.setattr(runtime, "show_library_logs", lambda: None)
    cli = importlib.import_module(f"rpmnet_jax.cli.{module}")
    monkeypatch.setattr(cli, "main", lambda: 0)
    with pytest.raises(SystemExit) as e:
        cli.entry()
    assert e.value.code == 0 and calls == ([module] if tuned else [])


_SHOW = ("import os; from rpmnet_jax.cli import runtime; "
         "runtime.run(lambda: print('tunables', os.environ.get('GLIBC_TUNABLES')) or 0, huge_pages={})")


def _tunables(huge_pages: bool, **env) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("GLIBC_TUNABLES", "RPMNET_NO_HUGEPAGES")} | env
    out = subprocess.run([sys.executable, "-c", _SHOW.format(huge_pages)], capture_output=True, text=True,
                         env=dict(env, RPMNET_COMPILATION_CACHE="off"), check=True)
    return out.stdout.split("tunables ", 1)[1].strip()


@pytest.mark.slow  # two re-executed interpreters (~20 s)
def test_training_reexecutes_with_the_tunables_and_the_opt_out_holds():
    if not (sys.platform.startswith("linux") and runtime._thp_available()):
        pytest.skip("transparent huge pages are not available on this machine")
    assert "glibc.malloc.hugetlb=1" in _tunables(True) and "trim_threshold" in _tunables(True)
    assert _tunables(True, RPMNET_NO_HUGEPAGES="1") == "None"
    assert _tunables(False) == "None"


class _Terminal:
    """A stream that says it is a terminal, and keeps what is written to it."""

    def __init__(self, tty=True):
        self.text, self.tty = [], tty

    def isatty(self):
        return self.tty

    def write(self, s):
        self.text.append(s)

    def flush(self):
        pass


def test_progress_bars_follow_the_stages_on_a_terminal_only():
    for tty, quiet in ((True, False), (False, False), (True, True)):
        stream = _Terminal(tty)
        bars = runtime.ProgressBars(quiet, stream=stream)
        for stage, total in (("network edges", 3), ("refinement round 1", 2)):
            for done in range(1, total + 1):
                bars(stage, done, total)
        bars.close()
        out = "".join(stream.text)
        if tty and not quiet:
            assert "network edges" in out and "3/3" in out and "refinement round 1" in out and "2/2" in out
        else:
            assert out == ""  # a log file, a pipe or --quiet: nothing drawn
