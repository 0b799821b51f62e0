"""The docs site (docs/, mkdocs.yml) and README.md: the site builds with ``mkdocs build
--strict`` (a broken link or anchor, or a page missing from the nav, fails), the command
reference equals each command's ``--help``, and every code block a page shows is checked:

- ``python`` blocks run. The library example (``<!-- library-example -->``, in README.md and
  in getting-started.md) runs as it stands; the GP library's overview (``<!-- gp-example
  -->``) uses placeholders (``S``, ``A``, ``x``, ``y``, ``xq``, ``var_tol``, ``mask``) that
  the test defines first; the two worked examples (``<!-- excerpt: PATH -->``: the corridor's
  env and the constant agent, annotated excerpts of PATH that leave parts out) are run in
  PATH's namespace with the parts they leave out taken from PATH, and must behave as PATH's
  own classes do.
- ``bash`` blocks show commands and are not run (they train for minutes or hours, install
  packages, or start the test suite itself): each ``python scripts/NAME.py`` or ``trl-dgpq
  NAME`` line is parsed by that command's own parser (and a train line's settings are
  resolved, so a preset or setting that no longer exists fails), each ``make TARGET`` must be
  a target of the Makefile, other scripts must exist; ``pip install`` and ``pytest`` lines are
  exempt (they install or run the suite).
- ``toml`` blocks are sweep files: read and every experiment resolved by the sweep's reader.
- ``text`` blocks are output or layout (the command reference's ``--help`` texts, checked
  above; the architecture's tree of folders) and are exempt.
A block of any other kind, or without one, fails: mark it or give it a check here.
"""
from __future__ import annotations

import argparse
import importlib
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]
FENCE = re.compile(r"(?:<!-- ([^>]*?) -->\n)?```(\w*)\n(.*?)```", re.S)
COMMANDS = ("train", "evaluate", "plot", "report", "sweep", "reproduce", "tune")


def blocks(kind=None):
    """(page, marker, language, code) of every fenced block, in README.md and under docs/."""
    out = []
    for page in PAGES:
        for m in FENCE.finditer(page.read_text()):
            if kind is None or m.group(2) == kind:
                out.append((page.relative_to(ROOT).as_posix(), (m.group(1) or "").strip(), m.group(2), m.group(3)))
    return out


def test_the_docs_build_strict(tmp_path):
    pytest.importorskip("mkdocs", reason="mkdocs is not installed: pip install -e '.[docs]' (make test does)")
    pytest.importorskip("material", reason="mkdocs-material is not installed: pip install -e '.[docs]'")
    pytest.importorskip("mkdocstrings_handlers.python", reason="mkdocstrings[python] is not installed: "
                                                              "pip install -e '.[docs]'")
    out = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet",
                          "-f", str(ROOT / "mkdocs.yml"), "-d", str(tmp_path / "site")],
                         capture_output=True, text=True, timeout=300, cwd=tmp_path,
                         env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert out.returncode == 0, out.stdout + out.stderr
    assert (tmp_path / "site" / "domains" / "liquidation" / "index.html").exists()


def test_every_page_is_in_the_nav_and_every_figure_is_shown():
    nav = (ROOT / "mkdocs.yml").read_text()
    for page in (ROOT / "docs").rglob("*.md"):
        assert page.relative_to(ROOT / "docs").as_posix() in nav, page
    text = "".join(p.read_text() for p in PAGES)
    for figure in list((ROOT / "docs").glob("*.png")) + list((ROOT / "docs").glob("*.gif")):
        assert f"{figure.name})" in text, f"docs/{figure.name} is shown on no page"


def test_the_command_reference_is_each_commands_help():
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import docs_reference
    finally:
        sys.path.remove(str(ROOT / "scripts"))
    out = docs_reference.stale((ROOT / "docs" / "commands.md").read_text())
    assert not out, f"docs/commands.md differs from --help of {out}: run python scripts/docs_reference.py"


def test_every_code_block_is_checked_or_marked():
    known = {"python", "bash", "toml", "text"}
    for page, marker, lang, code in blocks():
        assert lang in known, f"{page}: a ```{lang or '(no language)'} block: mark it ```text or check it here"
        if lang == "python":
            assert marker == "library-example" or marker == "gp-example" or marker.startswith("excerpt: "), \
                f"{page}: a python block with no check: {code.splitlines()[0]!r}"


def test_the_library_example_runs_on_every_page_that_shows_it(capsys):
    found = [(page, code) for page, marker, _, code in blocks("python") if marker == "library-example"]
    assert {page for page, _ in found} == {"README.md", "docs/getting-started.md"}
    assert found[0][1] == found[1][1], "README's library example and getting-started.md's differ"
    exec(compile(found[0][1], found[0][0], "exec"), {})
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("tensor([") and len(out) == 4 and out[-1].endswith("dtype=torch.float64)")


def test_the_gp_library_overview_runs():
    import torch
    (page, _, _, code), = [b for b in blocks("python") if b[1] == "gp-example"]
    g = torch.Generator().manual_seed(0)
    S, A = 2, 3
    namespace = dict(S=S, A=A, x=torch.rand(S, A, 2, generator=g, dtype=torch.float64),
                     y=torch.rand(S, A, generator=g, dtype=torch.float64),
                     xq=torch.rand(S, A, 5, 2, generator=g, dtype=torch.float64), var_tol=0.1, mask=None)
    exec(compile(code, page, "exec"), namespace)
    assert namespace["mean"].shape == namespace["var"].shape == (S, A, 5)
    assert (namespace["gp"].size == 1).all()  # emptied by reset, then one gated add: each GP took the point


def excerpt(path):
    (page, _, _, code), = [b for b in blocks("python") if b[1] == f"excerpt: {path}"]
    name = path.removesuffix(".py").replace("/", ".")
    module = importlib.import_module(name if name.startswith("trl_dgpq.") else "trl_dgpq." + name)
    namespace = dict(vars(module))
    exec(compile(code, page, "exec"), namespace)
    return module, namespace


def test_the_corridor_excerpt_behaves_as_the_corridor():
    import torch
    module, ns = excerpt("envs/corridor/env.py")
    assert ns["Env"] is ns["CorridorEnv"] is not module.CorridorEnv

    class Shown(ns["CorridorEnv"]):  # with the two parts the page leaves to the file
        def __init__(self, seeds=(0,), cfg=None, device="cpu", **overrides):
            super().__init__(seeds, cfg, device, **overrides)
            self.cell = torch.zeros(self.num_seeds, dtype=torch.long, device=self.device)
        _observe = module.CorridorEnv._observe

    for cfg in (dict(length=6, slip=0.0, max_steps=12), dict(length=8, slip=0.25, max_steps=30)):
        real, shown = module.CorridorEnv([0, 1, 2], **cfg), Shown([0, 1, 2], **cfg)
        a, b = real.reset(), shown.reset()
        for t in range(40):
            action = torch.tensor([1, t % 2, (t // 3) % 2])
            a["action"], b["action"] = action, action.clone()
            a, next_a = real.step_and_maybe_reset(a)
            b, next_b = shown.step_and_maybe_reset(b)
            for key in ("observation", "reward", "terminated", "truncated"):
                assert torch.equal(a["next", key], b["next", key]), (cfg, t, key)
            a, b = next_a, next_b


def test_the_constant_agent_excerpt_behaves_as_the_constant_agent():
    import torch
    from trl_dgpq.envs.corridor.env import CorridorEnv
    module, ns = excerpt("trl_dgpq/agents/constant.py")
    shown, real = ns["ConstantAgent"], module.ConstantAgent
    assert shown is not real
    info = CorridorEnv([0, 1]).info
    for action in ("right", "left", "0", "1"):
        cfg = ns["ConstantConfig"](action=action)
        assert torch.equal(shown.make(cfg, info, [0, 1]).act(None), real.make(cfg, info, [0, 1]).act(None))
    for action, message in (("up", "no action 'up'"), ("2", "not among this env's 2 actions")):
        with pytest.raises(ValueError, match=message):
            shown.resolve_config(ns["ConstantConfig"](action=action), info)


class Parsed(BaseException):  # not an Exception: no command's handler catches it
    def __init__(self, parser, namespace):
        super().__init__()
        self.parser, self.namespace = parser, namespace


def parse(name, args, monkeypatch):
    """``args`` through command ``name``'s own parser (its main, stopped right after parsing)."""
    original = argparse.ArgumentParser.parse_args

    def parse_args(self, argv=None, namespace=None):
        raise Parsed(self, original(self, argv, namespace))
    with monkeypatch.context() as m:
        m.setattr(argparse.ArgumentParser, "parse_args", parse_args)
        try:
            importlib.import_module(f"trl_dgpq.commands.{name}").main(args)
        except Parsed as parsed:
            return parsed
        except SystemExit as exit:
            pytest.fail(f"{name} {shlex.join(args)}: refused by its parser (exit {exit.code})")
    pytest.fail(f"{name} {shlex.join(args)}: the command parsed nothing")


def shell_commands():
    """(page, words) of every command in a bash block; optional parts ``[...]`` given."""
    out = []
    for page, _, _, code in blocks("bash"):
        for line in code.splitlines():
            words = [w.strip("[]") for w in shlex.split(line, comments=True)]
            command = []
            for word in words + ["&&"]:
                if word == "&&":
                    if command:
                        out.append((page, command))
                    command = []
                elif word:
                    command.append(word)
    return out


def test_every_shell_command_a_page_shows_parses(monkeypatch, capsys):
    from trl_dgpq.collectors.experiment import resolve_config
    from trl_dgpq.commands.train import given_settings
    targets = set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M))
    seen = set()
    for page, words in shell_commands():
        where = f"{page}: {shlex.join(words)}"
        if words[0] == "make":  # a target, and variables the Makefile reads (make mutate MODULES=...)
            make = (ROOT / "Makefile").read_text()
            assert len(words) >= 2 and words[1] in targets, where
            for word in words[2:]:
                assert re.fullmatch(r"[A-Z]+=.+", word) and f"$({word.split('=')[0]})" in make, where
        elif words[0] in ("pip", "pytest"):
            continue  # installs, or runs this suite: exempt
        elif words[0] == "trl-dgpq" or (words[0] == "python" and words[1].startswith("scripts/")):
            name, args = (words[1], words[2:]) if words[0] == "trl-dgpq" else (Path(words[1]).stem, words[2:])
            if name not in COMMANDS:
                assert (ROOT / "scripts" / f"{name}.py").exists(), where
                continue
            parsed = parse(name, args, monkeypatch)
            seen.add(name)
            ns = parsed.namespace
            # resolved unless it reads a run or a study's preset that the lines before it write
            if name == "train" and not (ns.resume or ns.config or ns.list_presets or ns.preset == "tuned"):
                try:
                    resolve_config(given_settings(ns, parsed.parser))
                except ValueError as err:
                    pytest.fail(f"{where}: {err}")
        else:
            pytest.fail(f"{where}: a command this test does not know; check it here or show it as text")
    capsys.readouterr()
    assert {"train", "plot", "report", "evaluate", "sweep", "reproduce", "tune"} <= seen


def test_every_sweep_file_a_page_shows_is_read(tmp_path):
    from trl_dgpq.collectors.sweep import read_sweep_file
    found = blocks("toml")
    assert found
    for i, (page, _, _, code) in enumerate(found):
        path = tmp_path / f"{i}.toml"
        path.write_text(code)
        experiments = read_sweep_file(path)
        assert experiments, page


def test_readmes_links_reach_files_and_it_stays_short():
    text = (ROOT / "README.md").read_text()
    # the hand-written part stays short; the results block is generated, a row per published claim
    # (128 lines with liquidation on one reward's 20 claims, 2026-11-29)
    written = re.sub(r"<!-- results: .*? -->\n.*?<!-- /results -->", "", text, flags=re.S)
    assert len(written.splitlines()) <= 100, "README.md is for a visitor's two minutes: the rest goes in docs/"
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    assert links
    for link in links:
        if not re.match(r"\w+://", link):
            assert (ROOT / link).exists(), f"README.md links to {link}, which does not exist"


# ------------------------------------------------------------ numbers a reader can trace
PUBLISHED = ROOT / "results" / "report"
DOMAIN_PAGES = {"square": "square.md", "push": "push.md", "gym": "gym.md", "f16": "f16.md",
                "liquidation": "liquidation.md"}


def prose_pages():
    """README.md and the docs' own pages (not the published report the site shows, docs/results)."""
    return [p for p in PAGES if "results" not in p.relative_to(ROOT).parts[:2]]


def test_pages_speak_of_the_suites_goals_in_words_not_issue_numbers():
    """A reader cannot look an issue number up: README.md, the docs and the published report say what a
    goal is instead."""
    found = [f"{p.relative_to(ROOT)}: {line.strip()[:80]}" for p in prose_pages() + sorted(PUBLISHED.glob("*.md"))
             for line in p.read_text().splitlines() if re.search(r"\bissues? \d+", line, re.I)]
    assert not found, "\n".join(found)


def test_the_readmes_results_are_the_published_summary():
    """README.md's results block is results/report/summary.md, which the report writes from the
    published data (scripts/docs_reference.py copies it in)."""
    sys.path.insert(0, str(ROOT / "scripts"))
    import docs_reference
    readme = (ROOT / "README.md").read_text()
    block = docs_reference.RESULTS.search(readme)
    assert block, "README.md has no <!-- results: ... --> block"
    if (PUBLISHED / "summary.md").is_file():
        assert docs_reference.with_summary(readme) == readme, "run python scripts/docs_reference.py"
    # the section around the block says nothing else about runs: the block and links
    section = readme.split("## Results in short", 1)[1].split("\n## ", 1)[0]
    outside = section.replace(block.group(0), "")
    assert not re.search(r"\d\.\d", outside), outside


def test_each_domain_page_includes_its_published_section_and_dates_its_research_log():
    """A domain's results are its section of the published report, included (not copied); what was
    measured along the way is a research log whose entries each say when ("### 2026-11-26: ...") and
    give the command."""
    for name, page in DOMAIN_PAGES.items():
        text = (ROOT / "docs" / "domains" / page).read_text()
        assert f'--8<-- "{name}.md"' in text, f"{page} does not include its section of the report"
        if "## Research log" in text:
            log = text.split("## Research log", 1)[1].split("\n## ", 1)[0]
            entries = re.split(r"\n### ", log)[1:]
            assert entries, page
            for entry in entries:
                assert re.match(r"\d{4}-\d\d-\d\d", entry), f"{page}: an entry without its date: {entry[:60]}"
                assert re.search(r"(python scripts/\w+\.py|trl-dgpq \w+|make \w+)", entry), \
                    f"{page}: an entry without its command: {entry[:60]}"
