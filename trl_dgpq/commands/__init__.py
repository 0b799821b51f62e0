"""The suite's commands; ``scripts/<name>.py`` and ``trl-dgpq <name>`` (``trl_dgpq.__main__``)
run ``trl_dgpq.commands.<name>.main``."""
import sys

ENTRY = None  # "trl-dgpq" when run through the console command


def prog(name: str) -> str:
    """The command's name as the user typed it, for usage lines and messages."""
    return f"{ENTRY} {name}" if ENTRY else f"{name}.py"


def command(name: str) -> str:
    """How to run command ``name`` the way this one was run, for "continue with" hints."""
    return f"{ENTRY} {name}" if ENTRY else f"python scripts/{name}.py"


def quote(path) -> str:
    """A path as a printed hint gives it: pasted into a shell it names the same file (spaces, quotes)."""
    import shlex
    return shlex.quote(str(path))


def run(name: str, argv=None) -> int:
    """Command ``name`` on ``argv`` (default: the process's): ``--help`` and an unknown flag are
    answered before the command's heavy imports (``early``), the rest by its ``main``."""
    import importlib

    from .early import answer
    argv = list(sys.argv[1:] if argv is None else argv)
    code = answer(name, argv)
    if code is not None:
        return code
    return importlib.import_module(f"trl_dgpq.commands.{name}").main(argv)


def guarded(name: str, body) -> int:
    """``body()``'s exit code; a bad request or a file that cannot be read or written -> one
    line and 2, Ctrl-C -> one line and 130 (never a traceback for these)."""
    try:
        return body()
    except (ValueError, OSError) as err:
        print(f"{prog(name)}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog(name)}: interrupted", file=sys.stderr)
        return 130
