"""Every script in scripts/ answers --help, and bench.py each of its sub-commands' --help: argparse
formats help strings with %, so a stray "95 % CI" in one crashes the whole help (it did)."""
import runpy
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parent.parent / "scripts"


def help_of(monkeypatch, capsys, script, *argv):
    monkeypatch.setattr(sys, "argv", [str(script), *argv, "--help"])
    monkeypatch.syspath_prepend(str(SCRIPTS))
    with pytest.raises(SystemExit) as ended:
        runpy.run_path(str(script), run_name="__main__")
    assert ended.value.code in (0, None)
    return capsys.readouterr().out


@pytest.mark.parametrize("script", sorted(p.name for p in SCRIPTS.glob("*.py") if "__main__" in p.read_text()
                                          and "run it as" not in p.read_text()))  # bench_parity: via bench.py
def test_each_script_answers_help(script, monkeypatch, capsys):
    assert "usage:" in help_of(monkeypatch, capsys, SCRIPTS / script)


def test_each_bench_sub_command_answers_help(monkeypatch, capsys):
    top = help_of(monkeypatch, capsys, SCRIPTS / "bench.py")
    subs = top.split("{", 1)[1].split("}", 1)[0].split(",")
    assert {"qhat", "same-curves", "bound", "parity"} <= set(subs)
    for name in subs:
        assert f"usage: bench.py {name}" in help_of(monkeypatch, capsys, SCRIPTS / "bench.py", name)
