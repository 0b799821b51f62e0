"""scripts/mutate.py: a retest of the survivors with only the tests given."""
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
