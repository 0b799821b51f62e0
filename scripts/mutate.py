#!/usr/bin/env python
"""Mutation testing with mutmut 3 on a few modules, with the tests that cover them.

    make mutate MODULES="envs/f16 collectors/evaluate.py"
    make mutate MODULES=collectors/evaluate.py TESTS="tests/test_evaluate.py" K="not push"
    python scripts/mutate.py envs/f16 --tests tests/test_f16.py -k "not slow"
    python scripts/mutate.py envs/f16 --again      # after new tests: retest only the survivors
    python scripts/mutate.py envs/f16 --again --tests tests/test_f16.py -k model   # ... with the new tests only
    python scripts/mutate.py collectors/sweep.py --tests tests/test_sweep.py -k reuse --only '*x_reuse__mutmut_*'
                                                   # one function's mutants only

Not part of ``make test`` or CI: it is slow (every mutant reruns the tests that reach its function).
Needs the ``mutate`` extra (``pip install -e ".[mutate]"``).

The layout problem. mutmut copies the code into ``mutants/`` and names each mutant by its file's
path (``envs/f16/env.py`` -> module ``envs.f16.env``); its trampolines switch a mutant on only
when the running function's ``__module__`` has that name. Here ``envs/`` and ``collectors/``
install as ``trl_dgpq.envs`` and ``trl_dgpq.collectors`` (setup.py's package_dir), so the
functions' modules are ``trl_dgpq.envs.f16.env`` and, worse, the editable install's finder maps
``trl_dgpq.envs`` to the checkout's ``envs/``: a copy in ``mutants/envs/`` would never be
imported, and every mutant would "survive". So this script first builds a staging tree in the
installed layout -- ``mutants/trl_dgpq/`` with ``envs/`` and ``collectors/`` inside it, beside a
copy of ``tests/``, ``scripts/``, ``configs/`` ... -- and runs mutmut there: mutmut's own copy
``mutants/mutants/`` then holds ``trl_dgpq/envs/f16/env.py``, whose module name is the one the
code runs under, and which comes first on ``sys.path`` (``PYTHONPATH`` too, for subprocesses)
ahead of the editable finder (the last entry of ``sys.meta_path``). mutmut checks both halves
itself: its forced-fail run (every trampoline raises) must fail a test, and its stats run must
record trampoline hits under the mutants' names, or it stops.

Score: killed / total per module, a timeout counted as killed (the tests noticed); survivors and
mutants no selected test reaches are listed. Their diffs go to ``mutants/survivors.diff``.
"""
from __future__ import annotations

import argparse
import fnmatch
import json
import os
import re
import shutil
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
STAGE = ROOT / "mutants"  # the staging tree, mutants/<modules> (main sets it); mutmut's own copy is STAGE / "mutants"
# checkout folder -> where it lives in the installed package (setup.py's package_dir)
LAYOUT = {"envs": "trl_dgpq/envs", "collectors": "trl_dgpq/collectors"}
SKIP = {".git", ".venv", "runs", "mutants", "site", "build", "dist", "__pycache__", ".pytest_cache"}


def installed_path(module: str) -> str:
    """``envs/f16/``, ``trl_dgpq/envs/f16`` or ``trl_dgpq.envs.f16`` -> ``trl_dgpq/envs/f16``
    (a folder, or a file with its .py) as the package installs it."""
    m = module.strip().rstrip("/")
    if "/" not in m and not m.endswith(".py"):                   # a dotted name
        m = m.replace(".", "/")
    parts = m.split("/")
    if parts[0] == "trl_dgpq" and len(parts) > 1 and parts[1] in LAYOUT:
        parts = parts[1:]
    checkout = "/".join(parts)
    if not (ROOT / checkout).exists() and (ROOT / (checkout + ".py")).is_file():
        checkout += ".py"
    if not (ROOT / checkout).exists():
        raise SystemExit(f"mutate: {module} is not a file or folder of this checkout")
    head, _, rest = checkout.partition("/")
    return f"{LAYOUT[head]}/{rest}".rstrip("/") if head in LAYOUT else checkout


def dotted(installed: str) -> str:
    return installed.removesuffix(".py").replace("/", ".")


def default_tests(installed: list[str]) -> list[str]:
    """The test files that name a module (``trl_dgpq.envs.f16``), or its folder's last part."""
    found = []
    for test in sorted((ROOT / "tests").glob("test_*.py")):
        text = test.read_text()
        for path in installed:
            name = dotted(path)
            parent, _, leaf = name.rpartition(".")
            if name in text or re.search(rf"from {re.escape(parent)} import [^\n]*\b{leaf}\b", text):
                found.append(f"tests/{test.name}")
                break
    return found


def stage(sources: list[str], tests: list[str], pytest_args: list[str]) -> None:
    """The checkout in the installed layout under STAGE, with a pyproject.toml telling mutmut
    what to mutate and which tests to run."""
    if STAGE.exists():
        shutil.rmtree(STAGE)
    STAGE.mkdir(parents=True)
    patterns = shutil.ignore_patterns("__pycache__", "*.egg-info", "*.pyc")

    def ignore(folder: str, names: list) -> set:
        # and links: a checkout may link trl_dgpq/envs to ../envs (the installed layout, for running
        # it with PYTHONPATH); the staging tree lays those folders out itself
        laid_out = {str((ROOT / checkout).resolve()) for checkout in LAYOUT}
        return set(patterns(folder, names)) | {n for n in names if os.path.islink(os.path.join(folder, n))
                                               and os.path.realpath(os.path.join(folder, n)) in laid_out}
    tops = []
    for item in sorted(ROOT.iterdir()):
        if item.name in SKIP or item.name.startswith(".") or item.name in LAYOUT or item.name.endswith(".egg-info"):
            continue
        (shutil.copytree(item, STAGE / item.name, ignore=ignore) if item.is_dir()
         else shutil.copy2(item, STAGE / item.name))
        tops.append(item.name)
    for checkout, installed in LAYOUT.items():
        shutil.copytree(ROOT / checkout, STAGE / installed, ignore=ignore)
    also = [t for t in tops if t not in ("tests", "pyproject.toml")]
    config = {
        "source_paths": sources,
        "also_copy": also,                            # the whole package, whatever is mutated
        "pytest_add_cli_args_test_selection": tests + pytest_args,
        "pytest_add_cli_args": ["-p", "no:cacheprovider", "-p", "no:xdist"],
        "use_git_change_detection": False,
        "debug": False,
    }
    lines = ["", "[tool.mutmut]  # written by scripts/mutate.py"]
    lines += [f"{k} = {json.dumps(v)}" for k, v in config.items()]
    with open(STAGE / "pyproject.toml", "a") as f:
        f.write("\n".join(lines) + "\n")
    # mutmut's copy must exist before it starts: PYTHONPATH names it, and a path that is missing
    # when the interpreter starts is cached as having no modules (sys.path_importer_cache), so
    # the package would come from the editable install and no mutant would ever run.
    (STAGE / "mutants").mkdir()


SELECTION = "pytest_add_cli_args_test_selection = "


def selection() -> list[str]:
    """The staged run's test selection (the line ``stage`` wrote into its pyproject.toml)."""
    line = next(x for x in (STAGE / "pyproject.toml").read_text().splitlines() if x.startswith(SELECTION))
    return json.loads(line[len(SELECTION):])


def select(tests: list[str]) -> None:
    """Set the staged run's test selection."""
    path = STAGE / "pyproject.toml"
    lines = [SELECTION + json.dumps(tests) if x.startswith(SELECTION) else x for x in path.read_text().splitlines()]
    path.write_text("\n".join(lines) + "\n")


def verdicts() -> dict:
    """{meta file: mutmut's exit code by mutant} of the staged run."""
    return {meta: json.loads(meta.read_text())["exit_code_by_key"]
            for meta in (STAGE / "mutants").rglob("*.py.meta")}


def keep(before: dict, retested: set) -> None:
    """Put back the verdicts ``before`` of the mutants not retested (mutmut forgets them)."""
    for meta, codes in before.items():
        if not meta.is_file():
            continue
        data = json.loads(meta.read_text())
        now = data["exit_code_by_key"]
        for name, code in codes.items():
            if name not in retested:
                now[name] = code
        meta.write_text(json.dumps(data))


def mutmut(*args: str, env: dict) -> int:
    exe = Path(sys.executable).parent / "mutmut"
    return subprocess.call([str(exe), *args], cwd=STAGE, env=env)


def results() -> dict:
    """{source file (installed path): {mutant name: status}} from mutmut's meta files."""
    from mutmut.stats import status_by_exit_code
    out = {}
    for meta in sorted((STAGE / "mutants").rglob("*.py.meta")):
        codes = json.loads(meta.read_text())["exit_code_by_key"]
        out[str(meta.relative_to(STAGE / "mutants"))[:-len(".meta")]] = {
            k: status_by_exit_code[v] for k, v in codes.items()}
    return out


def report(modules: list[str], sources: list[str], found: dict, env: dict) -> list[str]:
    """Print killed / total per module and per file; return the names of the mutants run and not
    killed (survived, no tests), whose diffs go to survivors.diff."""
    caught = {"killed", "timeout", "caught by type check"}
    survivors = []
    print("\nmutation score (killed / total; a timeout counts as killed)")
    for module, source in zip(modules, sources):
        files = {f: s for f, s in found.items() if f == source or f.startswith(source.rstrip("/") + "/")}
        counts = Counter(s for statuses in files.values() for s in statuses.values())
        total, killed = sum(counts.values()), sum(counts[c] for c in caught)
        pct = f"{100 * killed / total:.0f} %" if total else "-"
        rest = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()) if s not in caught)
        print(f"  {module}: {killed} / {total} killed ({pct}){'; ' + rest if rest else ''}")
        for f, statuses in sorted(files.items()):
            c = Counter(statuses.values())
            if len(files) > 1 and statuses:
                k = sum(c[x] for x in caught)
                print(f"      {f}: {k} / {len(statuses)}")
            unchecked = sorted(name for name, s in statuses.items() if s == "not checked")
            for name, s in sorted(statuses.items()):
                if s not in caught and (s != "not checked" or len(unchecked) <= 20):
                    print(f"        {s}: {name}")
                if s not in caught and s != "not checked":
                    survivors.append(name)
            if len(unchecked) > 20:   # a run with --only, or stopped early: a count, not a list
                print(f"        not checked: {len(unchecked)} ({unchecked[0]} ...)")
    # the diffs of the mutants run and not killed (one `mutmut show` each: not the unchecked ones)
    with open(STAGE / "survivors.diff", "w") as f:
        for name in survivors:
            f.write(subprocess.run([str(Path(sys.executable).parent / "mutmut"), "show", name], cwd=STAGE,
                                   env=env, capture_output=True, text=True).stdout + "\n")
    if survivors:
        print(f"their diffs: {STAGE / 'survivors.diff'} (or: cd {STAGE} && mutmut show NAME)")
    return survivors


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("modules", nargs="+", help="files or folders: envs/f16, collectors/evaluate.py, trl_dgpq/agents/dqn.py")
    p.add_argument("--tests", nargs="*", default=None,
                   help="test files or node ids (default: the test files that import the modules)")
    p.add_argument("-k", dest="keyword", default=None, help="pytest -k expression on those tests")
    p.add_argument("--only", nargs="+", default=[], metavar="PATTERN",
                   help="mutmut's mutant names to run (fnmatch), e.g. '*x_reuse__mutmut_*' for one function")
    p.add_argument("--max-children", type=int, default=None, help="parallel mutants (default: the cores)")
    p.add_argument("--again", action="store_true",
                   help="keep the last run's mutants; copy tests/ again and retest its survivors and the "
                        "mutants it did not reach (a run stopped early) only, with the first run's tests (its -k "
                        "too); with --tests (and -k), its survivors only, with those tests only (they passed the "
                        "first run's: e.g. the file with the new tests); the other mutants keep their verdicts")
    a = p.parse_args(argv)
    try:
        import mutmut as _  # noqa: F401
    except ImportError:
        raise SystemExit('mutate: mutmut is not installed: pip install -e ".[mutate]"')

    sources = [installed_path(m) for m in a.modules]
    global STAGE  # one tree per set of modules: two runs on different modules can go on side by side
    STAGE = ROOT / "mutants" / "+".join(dotted(s).removeprefix("trl_dgpq.") for s in sources)
    tests = a.tests if a.tests else default_tests(sources)
    if not tests:
        raise SystemExit(f"mutate: no test file names {', '.join(map(dotted, sources))}: give --tests")
    pytest_args = ["-k", a.keyword] if a.keyword else []
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(STAGE / "mutants"), *filter(None, [os.environ.get("PYTHONPATH")])]))
    env.pop("MUTANT_UNDER_TEST", None)
    extra = [f"--max-children={a.max_children}"] if a.max_children else []

    start = time.time()
    if a.again:
        if not (STAGE / "mutants").is_dir():
            raise SystemExit("mutate: no earlier run in mutants/ to continue")
        shutil.rmtree(STAGE / "tests")
        shutil.copytree(ROOT / "tests", STAGE / "tests", ignore=shutil.ignore_patterns("__pycache__"))
        # With --tests, survivors only: they passed every test of the earlier run, so only the given (new)
        # tests can kill them; a mutant that run never reached still needs all of its tests.
        retest = ("survived",) if a.tests else ("survived", "not checked")
        again = [n for statuses in results().values() for n, s in statuses.items() if s in retest]
        again = [n for n in again if not a.only or any(fnmatch.fnmatch(n, pat) for pat in a.only)]
        print(f"mutate: retesting {len(again)} mutants ({' and '.join(retest)}) with the tests as they are now")
        before = verdicts()
        if a.tests:
            first = selection()
            select(tests + pytest_args)
        try:
            rc = mutmut("run", *extra, *again, env=env) if again else 0
        finally:
            if a.tests:
                select(first)
            # mutmut resets every verdict when its config (the selection) changes, and records only the
            # mutants a named run ran: the others keep what the earlier runs found
            keep(before, set(again))
    else:
        print(f"mutate: {', '.join(sources)} with {' '.join(tests + pytest_args)}")
        stage(sources, tests, pytest_args)
        rc = mutmut("run", *extra, *a.only, env=env)
    minutes = (time.time() - start) / 60
    found = results()
    if not found:
        print("mutate: mutmut wrote no results", file=sys.stderr)
        return rc or 1
    report(a.modules, sources, found, env)
    load = os.getloadavg()
    print(f"mutmut took {minutes:.1f} min (load average now {load[0]:.1f}, {load[1]:.1f}, {load[2]:.1f}; "
          f"{os.cpu_count()} cores)")
    return rc


if __name__ == "__main__":
    sys.exit(main())
