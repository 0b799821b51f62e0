"""scripts/mutate.py: a retest of the survivors with only the tests given."""
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
import mutate  # noqa: E402


def test_again_with_tests_replaces_only_the_staged_test_selection(tmp_path, monkeypatch):
    (tmp_path / "pyproject.toml").write_text(
        '[project]\nname = "x"\n\n[tool.mutmut]  # written by scripts/mutate.py\n'
        'source_paths = ["trl_dgpq/dgpq.py"]\n'
        'pytest_add_cli_args_test_selection = ["tests/test_a.py", "tests/test_b.py", "-k", "not slow"]\n'
        'debug = false\n')
    monkeypatch.setattr(mutate, "STAGE", tmp_path)
    mutate.select(["tests/test_b.py", "-k", "new"])
    assert (tmp_path / "pyproject.toml").read_text() == (
        '[project]\nname = "x"\n\n[tool.mutmut]  # written by scripts/mutate.py\n'
        'source_paths = ["trl_dgpq/dgpq.py"]\n'
        'pytest_add_cli_args_test_selection = ["tests/test_b.py", "-k", "new"]\n'
        'debug = false\n')


def test_mutants_not_retested_keep_their_earlier_verdicts(tmp_path, monkeypatch):
    """mutmut resets every verdict when its config changes and records only the mutants a named run
    ran: ``keep`` puts back the earlier verdicts of the others, and leaves the retested ones' new ones."""
    meta = tmp_path / "mutants" / "trl_dgpq" / "m.py.meta"
    meta.parent.mkdir(parents=True)
    meta.write_text(json.dumps({"exit_code_by_key": {"a": 1, "b": 0, "c": None}, "other": 7}))
    monkeypatch.setattr(mutate, "STAGE", tmp_path)
    before = mutate.verdicts()
    meta.write_text(json.dumps({"exit_code_by_key": {"a": None, "b": 1, "c": None}, "other": 7}))   # b retested
    mutate.keep(before, {"b"})
    assert json.loads(meta.read_text()) == {"exit_code_by_key": {"a": 1, "b": 1, "c": None}, "other": 7}


def test_the_selection_is_read_back_as_written(tmp_path, monkeypatch):
    (tmp_path / "pyproject.toml").write_text('x = 1\npytest_add_cli_args_test_selection = ["tests/a.py", "-k", "k"]\n')
    monkeypatch.setattr(mutate, "STAGE", tmp_path)
    assert mutate.selection() == ["tests/a.py", "-k", "k"]
    mutate.select(["tests/b.py"])
    assert mutate.selection() == ["tests/b.py"]
