"""The suite's commands; ``scripts/<name>.py`` and ``trl-dgpq <name>`` (``trl_dgpq.__main__``)
run ``trl_dgpq.commands.<name>.main``."""

ENTRY = None  # "trl-dgpq" when run through the console command


def prog(name: str) -> str:
    """The command's name as the user typed it, for usage lines and messages."""
    return f"{ENTRY} {name}" if ENTRY else f"{name}.py"
