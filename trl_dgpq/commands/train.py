#!/usr/bin/env python
"""Run an agent on an environment for many seeds at once, into a run folder.

    python scripts/train.py                                   # square, dgpq, "shaped" preset, 8 seeds
    python scripts/train.py --preset report --seeds 3-7 --gp exact
    python scripts/train.py --agent random --episodes 20 --set env.noise=0.02
    python scripts/train.py --config runs/X/config.json --out runs/again    # repeat a recorded run
    python scripts/train.py --resume runs/X                                 # continue an interrupted run
    python scripts/train.py --resume runs/X --episodes 200                  # run it longer, as if asked from the start

Every setting of the run, the env and the agent is a flag (``--noise-var 0.2``)
and can be given as ``--set key=value`` (``--set gp.noise_var=0.2``); both are
generated from the config dataclasses, whose defaults they show. A preset
(``envs/<domain>/presets.py``) is applied first, flags on top.

Writes OUT/config.json, OUT/status.json, OUT/episodes.csv (rows appended as
episodes end) and OUT/checkpoint.pt. Same config and seeds -> identical
episodes.csv apart from the timing columns (wall_s, cpu_s, us_per_step).
Errors in what you asked for end in one line and exit code 2; an interrupted
run (Ctrl-C, SIGTERM) saves a checkpoint and exits 130 / 143.
"""
from __future__ import annotations

import argparse
import json
import re
import sys

from trl_dgpq.analysis import count, ms_per_seed_step
from trl_dgpq.collectors import runner
from trl_dgpq.collectors.experiment import cli_owners, describe, quiet_torchrl, resolve_config
from trl_dgpq.commands import command, prog, quote
from trl_dgpq.config import describe_default
from trl_dgpq.envs import domain, split_name
from trl_dgpq.presets import preset_table

PROCESS_FLAGS = ("out", "resume", "overwrite", "config", "set", "no_progress", "print_config", "yes", "list_presets")


class Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (argparse prints the whole usage first)
        self.exit(2, f"{self.prog}: error: {message}\n")


MANY_SEEDS = 256  # more in one run asks first: "--seeds 3201" is more likely a typo of "--seeds 3-201"


def confirm_many(n: int, yes: bool) -> None:
    """Go on with ``n`` seeds: at once if few or ``yes``; else ask on a terminal, refuse otherwise."""
    if n <= MANY_SEEDS or yes:
        return
    question = f"{n} seeds in one run (a range is A-B, e.g. --seeds 3-201)"
    if sys.stdin.isatty() and input(f"{question}: go on? [y/N] ").strip().lower() in ("y", "yes"):
        return
    raise ValueError(f"{question}: not confirmed; add --yes to run that many")


def section_name(config_class: str) -> str:
    """"DGPQConfig" -> "DGPQ", "RunConfig" -> "run": the --help section of a config's flags."""
    name = config_class.removesuffix("Config")
    return "run" if name == "Run" else name


def list_presets() -> str:
    """Every (env, agent) with presets, the env's default first, each with what it is: the settings it
    sets (what of the env's model they use marked), or for a study's preset the study it came from."""
    from trl_dgpq.envs import domains
    from trl_dgpq.presets import preset_overrides, tuned_entries
    lines = []
    for d in domains():
        for env, agent, _ in d.preset_tables():
            table = preset_table(env, agent)  # with a study's "tuned", if one was written
            default = d.default_preset(split_name(env)[1])
            studies = tuned_entries(env).get(agent) or {}
            lines.append(f"{env} {agent}")
            for name in sorted(table, key=lambda n: (n != default, n)):
                lines.append(f"  {name + (' (default)' if name == default else ''):<28} "
                             + about_preset(env, agent, name, preset_overrides(env, agent, name)[1], studies.get(name)))
    return "\n".join(lines)


def about_preset(env: str, agent: str, name: str, sections: dict, study=None, width: int = 110) -> str:
    """One line: a study's preset by its study, else the settings a preset sets, marked where they use
    the env's model."""
    from trl_dgpq.analysis.results import cli_value
    from trl_dgpq.envs import model_knowledge
    if study is not None:
        p = study.get("provenance", {})
        validated = " validated on " + seeds_text(p["validation"]["seeds"]) if p.get("validation") else ""
        text = (f"study {p.get('study_name', '?')}: the best of {p.get('trials', '?')} trials on seeds "
                f"{seeds_text(p.get('seeds') or [])}{validated}, by {p.get('objective', '?')}")
    else:
        items = [f"{s}.{k}={cli_value(v)}" for s in ("env", "agent") for k, v in sections[s].items()]
        text = ", ".join(items) if items else "the defaults"
    mark = "; uses the model" if model_knowledge(resolve_config(env=env, agent=agent, preset=name, seeds=[0])) else ""
    room = width - len(mark)                     # (the defaults count too: the square's shaped reward)
    return (text if len(text) <= room else text[:room - 3] + "...") + mark


def seeds_text(seeds) -> str:
    from trl_dgpq.analysis.results import seeds_text as text
    return text(seeds) if seeds else "?"


def make_parser() -> argparse.ArgumentParser:
    p = Parser(prog=prog("train"), description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default=None, help="run folder (default runs/<env>-<agent>-<preset>-<time>); "
                                               "refused if it holds a run, unless --overwrite")
    p.add_argument("--overwrite", action="store_true", help="replace the run in --out")
    p.add_argument("--resume", metavar="OUT", default=None,
                   help="continue the run in OUT from its last checkpoint; with --episodes and/or --env-steps, "
                        "run it (even a finished one) longer, exactly as if that length had been asked from the start")
    p.add_argument("--config", metavar="FILE", default=None,
                   help="start from a recorded config.json (flags override it)")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                   help="any setting, e.g. --set gp.noise_var=0.2 (repeatable)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--print-config", action="store_true",
                   help="print the resolved config (presets and flags applied) as JSON and exit; runs nothing")
    p.add_argument("--yes", action="store_true", help=f"run more than {MANY_SEEDS} seeds without asking")
    p.add_argument("--list-presets", action="store_true", help="list every env's presets for each agent and exit")
    add_setting_flags(p, cli_owners())
    return p


def add_setting_flags(p: argparse.ArgumentParser, settings: dict) -> None:
    """A flag per setting, in a group per config, from {key: [(config class name, leaf), ...]}
    (``cli_owners()``); each defaults to None, "not given"."""
    groups = {}
    for key, owners in settings.items():
        title = (f"{section_name(owners[0][0])} settings" if len(owners) == 1
                 else "settings of several envs or agents (each one's default)")
        if title not in groups:
            groups[title] = p.add_argument_group(
                title, "defaults in brackets are the dataclasses'; a preset may change them: --print-config "
                       "shows what applies" if title.startswith("run") else None)
        g = groups[title]
        flag = "--" + key.replace("_", "-")
        leaf = owners[0][1]
        if len(owners) == 1:
            text = f"{leaf.help} [{describe_default(leaf)}]"
            if leaf.choices:
                text += f" {{{', '.join(leaf.choices)}}}"
        elif len({lf.help for _, lf in owners}) == 1:  # the same name in several configs: each one's default
            text = leaf.help + " [" + "; ".join(
                f"{name.removesuffix('Config')}: {describe_default(lf)}"
                + (f" {{{', '.join(lf.choices)}}}" if lf.choices else "") for name, lf in owners) + "]"
        else:  # ... meaning something else in each (--reward): each one's own help, not the first's alone
            text = "; ".join(f"{name.removesuffix('Config')}: {lf.help} [{describe_default(lf)}]"
                             + (f" {{{', '.join(lf.choices)}}}" if lf.choices else "") for name, lf in owners)
        if leaf.type is bool:
            g.add_argument(flag, dest=key, action=argparse.BooleanOptionalAction, default=None, help=text)
        else:
            g.add_argument(flag, dest=key, default=None, metavar=key.upper(), help=text)


def length(run: dict) -> str:
    """What each seed runs: "50 episodes", or "20,000 env steps" (and the episode cap if it binds)."""
    if not run.get("env_steps"):
        return count(run["episodes"], "episode")
    cap = f" (at most {run['episodes']:,} episodes)" if run["episodes"] < run["env_steps"] else ""
    return f"{run['env_steps']:,} env steps{cap}"


def given_settings(args, parser, process=PROCESS_FLAGS) -> dict:
    """The settings named on the command line (flags other than the ``process`` flags, then --set)."""
    settings = {k: v for k, v in vars(args).items() if k not in process and v is not None}
    for item in args.set:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            parser.error(f"--set wants KEY=VALUE, got {item!r}")
        settings[key.strip()] = value
    return settings


def main(argv=None) -> int:
    quiet_torchrl()
    try:
        return _main(argv)
    except KeyboardInterrupt:  # Ctrl-C before the run started (a started run checkpoints instead)
        print("interrupted before the run started", file=sys.stderr)
        return 130


def attach_negative_lists(argv):
    """argparse reads ``--goal -0.3,0.2`` as two options (only plain negative numbers pass);
    join such a comma list of numbers to its flag: ``--goal=-0.3,0.2``."""
    out = []
    for token in argv:
        if (out and out[-1].startswith("--") and "=" not in out[-1]
                and re.fullmatch(r"-[\d.][\d.eE+-]*(,\s*-?[\d.][\d.eE+-]*)+,?", token)):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def _main(argv=None) -> int:
    parser = make_parser()
    args = parser.parse_args(attach_negative_lists(sys.argv[1:] if argv is None else list(argv)))
    settings = given_settings(args, parser)
    if args.list_presets:
        print(list_presets())
        return 0
    try:
        if args.resume:
            lengths = {k.removeprefix("run."): v for k, v in settings.items()
                       if k.removeprefix("run.") in runner.LENGTHS}
            if len(lengths) < len(settings) or args.config or args.out or args.overwrite:
                parser.error("--resume continues a run as it was configured: give no settings other than a longer "
                             "--episodes or --env-steps, and no --config, --out or --overwrite with it")
            folder = runner.RunFolder.existing(args.resume)
            try:
                config = runner.resumable_config(folder, lengthen=bool(lengths))
                if lengths:
                    config = runner.lengthen(folder, config, **lengths)
            except BaseException:
                folder.release()  # refused: the folder is free again at once
                raise
            print(f"resuming {folder.path}" + (f" ({length(config['run'])} per seed)" if lengths else ""))
            df = runner.resume(folder, config, progress=not args.no_progress)
        else:
            base = None
            if args.config:
                try:
                    with open(args.config) as f:
                        base = json.load(f)
                except (OSError, ValueError) as err:
                    parser.error(f"cannot read --config {args.config}: {err}")
            config = resolve_config(settings, base=base)
            if args.print_config:
                print(json.dumps(config, indent=2))
                return 0
            confirm_many(len(config["run"]["seeds"]), args.yes)
            runner.check_memory(config)
            run = config["run"]
            folder = runner.RunFolder.create(args.out, describe(config).replace("/", "-"), args.overwrite)
            print(f"{describe(config)}: {count(len(run['seeds']), 'seed')} x {length(run)} -> {folder.path}; "
                  f"{runner.disk_note(config)}")
            df = runner.start(config, folder, progress=not args.no_progress)
    except runner.Interrupted as stop:
        seeds = len(config["run"]["seeds"])   # episodes_done counts every seed's: say so
        print(f"{stop} after {stop.episodes_done:,} episodes summed over {count(seeds, 'seed')}; checkpoint saved. "
              f"Continue with: {command('train')} --resume {quote(stop.folder.path)}", file=sys.stderr)
        return stop.exit_code
    except ValueError as err:  # everything the user asked for is checked before any work
        parser.error(str(err))
    summarise(df, config)
    print(f"wrote {folder.path}/episodes.csv; plot: {command('plot')} {quote(folder.path)}")
    return 0


def summarise(df, config) -> None:
    """A few lines on the run; a domain adds its own (``summary`` in its analysis.py)."""
    steps = df.pivot(index="episode", columns="seed", values="steps")
    late = df[df.episode >= 3]
    line = f"steps per episode, median over seeds: episode 1: {steps.loc[1].median():g}"
    if len(late):
        line += f", episodes 3+: {late.steps.median():g}"
    d = domain(config["run"]["env"])
    means = d.terminated_means(split_name(config["run"]["env"])[1])
    print(f"{line}; terminated ({means}) in {df.terminated.mean():.0%} of episodes; "
          f"{ms_per_seed_step(df) * 1e3:.0f} us per seed-step")
    own = getattr(d.analysis(), "summary", None)
    for extra in own(df) if own else measure_line(df, d, split_name(config["run"]["env"])[1]):
        print(extra)


def measure_line(df, d, env_id) -> list:
    """The domain's measure early and late (the F-16's reward: its steps are always the cap),
    for domains without a ``summary`` of their own; none where the measure is the steps."""
    column, label = d.measure(env_id)
    if column == "steps":
        return []
    n = min(10, max(1, df.episode.max() // 2))
    per_seed = df.sort_values("episode").groupby("seed")[column]
    first, last = per_seed.head(n).mean(), per_seed.tail(n).mean()
    return [f"{label}, mean over seeds: first {n} episodes {d.format_measure(first, env_id)}, "
            f"last {n} {d.format_measure(last, env_id)}"]


if __name__ == "__main__":
    sys.exit(main())
