"""trl_dgpq/analysis/figures.py by hand: the log axis's ticks, the labels' formats, the runs' looks,
the title wrapping, saving, the data kept beside a figure, and the figures every run gets (read back
from the saved figure)."""
import lzma
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

from trl_dgpq.analysis import figures as fg
from trl_dgpq.analysis.runs import Run


# ------------------------------------------------------------------ ticks and labels
@pytest.mark.parametrize("lo, hi, integer, want", [
    (17, 40, False, [20, 30, 40]),                       # 1-2-5 gives 20 only, 1-2-3-5 gives 20 and 30
    (40, 17, False, [20, 30, 40]),                       # either order
    (1.5, 4, False, [1.5, 2, 3, 4]),
    (1.5, 4, True, [2, 3, 4]),                           # whole numbers only: 1.5 dropped
    (1, 1000, False, [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000]),   # the sparsest set: 1-2-5 already gives 3
    (2.1e5, 5.9e5, False, [3e5, 4e5, 5e5]),              # $210k-$590k: 1-2-5 gives one inside, 1-2-3-5 two
    (-5, 0, False, []),                                  # nothing positive: no tick
    # a lower end at 0 taken as 1e-12 of the top: 1-2-5 from 5e-12 (1e-12 and 2e-12 are below 3e-12) to 2
    (0, 3, False, [m * 10.0 ** e for e in range(-12, 1) for m in (1, 2, 5)][2:-1]),
    (1.01, 1.02, False, []),                             # no set puts a tick inside
    (0.1, 0.9, False, [0.1, 0.2, 0.5]),                  # below 1 too
])
def test_log_ticks_are_the_sparsest_mantissas_with_three_inside(lo, hi, integer, want):
    got = fg.LogTicks(integer=integer).tick_values(lo, hi)
    assert got == pytest.approx(want, rel=1e-12) and len(got) == len(want)


def test_log_ticks_ask_for_at_least_least_and_read_the_axes_view():
    assert fg.LogTicks().tick_values(1.5, 4) == [1.5, 2, 3, 4]                  # not whole numbers only by default
    assert fg.LogTicks(least=2).tick_values(17, 40) == [20, 30]
    assert fg.LogTicks(least=1).tick_values(17, 40) == [20]
    fig, ax = plt.subplots()
    ax.set_yscale("log")
    locator = fg.LogTicks()
    ax.yaxis.set_major_locator(locator)
    ax.set_ylim(17, 40)
    assert locator() == pytest.approx([20, 30, 40])
    plt.close(fig)


@pytest.mark.parametrize("value, want", [(350e3, "$350k"), (1.2e6, "$1.2M"), (2.5e9, "$2.5B"), (-2e5, "-$200k"),
                                         (1000, "$1k"), (999, "$999"), (0.5, "$0.5"), (-3, "-$3"),
                                         (123456, "$123k"), (1e6, "$1M"), (1e9, "$1B")])
def test_dollars(value, want):
    assert fg.dollars(value) == want and fg.dollars(value, 7) == want


def test_plain_is_the_shortest_number():
    assert (fg.plain(0.001), fg.plain(20.0), fg.plain(1e6), fg.plain(2.5, 0)) == ("0.001", "20", "1e+06", "2.5")


def test_a_log_axis_gets_the_locator_the_formatter_and_no_minor_labels():
    fig, ax = plt.subplots()
    fg.log_axis(ax, fg.dollars, integer=True, axis="x")
    assert ax.get_xscale() == "log" and ax.get_yscale() == "linear"
    loc = ax.xaxis.get_major_locator()
    assert isinstance(loc, fg.LogTicks) and (loc.least, loc.integer) == (3, True)
    assert ax.xaxis.get_major_formatter()(2e6, 0) == "$2M"
    assert isinstance(ax.xaxis.get_minor_formatter(), matplotlib.ticker.NullFormatter)
    fg.log_steps_axis(ax)
    loc = ax.yaxis.get_major_locator()
    assert ax.get_yscale() == "log" and isinstance(loc, fg.LogTicks) and loc.integer
    assert ax.yaxis.get_major_formatter()(200.0, 0) == "200"
    fg.log_axis(ax)
    assert not ax.yaxis.get_major_locator().integer and ax.yaxis.get_major_formatter()(0.5, 0) == "0.5"
    plt.close(fig)


def test_the_runs_looks_are_ten_colours_then_dashed_then_dash_dotted():
    tab10 = plt.get_cmap("tab10").colors
    assert fg.line_style(0) == dict(linestyle="-", color=tab10[0])
    assert fg.line_style(3) == dict(linestyle="-", color=tab10[3])
    assert fg.line_style(10) == dict(linestyle="--", color=tab10[0])
    assert fg.line_style(29) == dict(linestyle="-.", color=tab10[9])
    assert fg.line_style(30) == fg.line_style(0)
    assert len({(s["linestyle"], s["color"]) for s in map(fg.line_style, range(30))}) == 30
    assert plt.rcParams["axes.prop_cycle"] == fg.CYCLE


def test_an_episode_axis_ticks_whole_episodes():
    fig, ax = plt.subplots()
    fg.episode_axis(ax)
    loc = ax.xaxis.get_major_locator()
    for lo, hi in ((1, 3), (0, 3), (1, 4), (0, 7), (0, 40), (3, 250)):
        ticks = loc.tick_values(lo, hi)
        assert all(float(t).is_integer() for t in ticks), (lo, hi)
        step = ticks[1] - ticks[0]                                # 1, 2, 5 or 10 times a power of ten: not 2.5
        assert step / 10 ** np.floor(np.log10(step)) in (1, 2, 5, 10), (lo, hi, ticks)
    plt.close(fig)


# ------------------------------------------------------------------ titles and saving
def test_long_titles_are_wrapped_at_spaces_until_they_fit():
    fig, (a, b) = plt.subplots(1, 2, figsize=(4, 3))
    long = " ".join(["word"] * 30)
    fig.suptitle(long + " " + long)
    a.set_title(long)
    b.set_title("short")
    fg.fit_titles(fig)
    renderer = fig.canvas.get_renderer()
    assert fig._suptitle.get_window_extent(renderer).width <= fig.bbox.width - 8
    assert a.title.get_window_extent(renderer).width <= a.bbox.width
    assert "\n" in a.get_title() and a.get_title().replace("\n", " ") == long
    assert b.get_title() == "short"
    # a line break of the title's own is kept; the width stops shrinking at 12 characters
    d = plt.figure(figsize=(3, 1)).add_subplot()
    d.set_title("a short first line\n" + " ".join(["second"] * 20))
    fg.fit_titles(d.figure)
    assert d.get_title().split("\n")[0] == "a short first line" and d.get_title().count("\n") > 1
    for text, wrapped in (("ab ab ab ab ab", "ab ab ab ab\nab"),     # 14 characters: wrapped at 12, no further
                          ("abc abc abc a", "abc abc abc\na")):       # 13: wrapped at 11
        e = plt.figure(figsize=(0.2, 0.2)).add_subplot()
        e.set_title(text)
        fg.fit_titles(e.figure)
        assert e.get_title() == wrapped
    c = plt.figure(figsize=(1, 1)).add_subplot()
    c.set_title("a" * 40)                                      # no space to break at: left as it is
    fg.fit_titles(c.figure)
    assert c.get_title() == "a" * 40
    plt.close("all")


def test_save_titles_lays_out_writes_at_120_dpi_and_closes(tmp_path):
    from PIL import Image
    fig, ax = plt.subplots(figsize=(2, 1.5))
    ax.set_title("t")
    assert fg.save(fig, tmp_path / "a.png", "the title") == tmp_path / "a.png"
    assert fig._suptitle.get_text() == "the title" and fig.number not in plt.get_fignums()
    assert fig._suptitle.get_fontsize() == 9
    assert Image.open(tmp_path / "a.png").size == (240, 180)
    fig, ax = plt.subplots(figsize=(2, 1.5))
    fg.save(fig, tmp_path / "b.png")
    assert fig._suptitle is None
    fig, ax = plt.subplots(figsize=(2, 1.5), layout="constrained")
    ax.set_ylabel("y")
    fg.save(fig, tmp_path / "c.png")
    fig = plt.figure()
    other = plt.figure()                                          # made after it: the current figure stays open
    fg.save(fig, tmp_path / "e.png")
    assert other.number in plt.get_fignums() and fig.number not in plt.get_fignums()
    plt.close(other)
    plain = plt.figure(figsize=(2, 1.5))
    ax = plain.add_subplot()
    ax.set_ylabel("a label")
    before = ax.get_position().x0
    fg.save(plain, tmp_path / "d.png")
    assert ax.get_position().x0 != before                         # tight_layout moved the axes to fit


def test_what_a_figure_draws_is_kept_beside_it_and_read_back_only_where_it_is_trusted(tmp_path):
    from trl_dgpq.analysis.published import DATA, MANIFEST
    figs = tmp_path / "pub" / "figs"
    figs.mkdir(parents=True)
    data = {"a": [[1.0, 0.5], [0.25, 0.0]], "b": []}
    assert fg.save_drawn(figs / "x.json.xz", data) == figs / "x.json.xz"
    with lzma.open(figs / "x.json.xz", "rt") as f:
        assert f.read() == '{"a":[[1.0,0.5],[0.25,0.0]],"b":[]}'                # compact
    assert fg.load_drawn(figs / "x.json.xz") is None                       # not a publication: another run's?
    assert fg.load_drawn(figs / "x.json.xz", fresh=True) == data
    assert fg.load_drawn(figs / "y.json.xz", fresh=True) is None           # nothing there
    (tmp_path / "pub" / DATA).mkdir()
    (tmp_path / "pub" / DATA / MANIFEST).write_text("{}")
    assert fg.load_drawn(str(figs / "x.json.xz")) == data


# ------------------------------------------------------------------ the figures every run gets
def a_run(path, rows):
    """rows: (seed, episode, steps, wall_s)."""
    df = pd.DataFrame([dict(seed=s, episode=e, steps=n, wall_s=w) for s, e, n, w in rows])
    return Run(Path(path), df, {"run": {"env": "square", "agent": "dgpq", "preset": "p"}, "env": {}, "agent": {}})


def test_the_episode_figures_draw_each_runs_median_and_iqr_per_episode(tmp_path, drawn):
    """Steps 10, 20, 60 of three seeds at episode 1 (median 20, IQR 15-40), 4, 4, 4 at episode 2;
    wall time 1 ms a step, then 2."""
    rows = [(s, 1, n, n * 1e-3) for s, n in enumerate((10, 20, 60))] + [(s, 2, 4, 8e-3) for s in range(3)]
    one, two = a_run("a", rows), a_run("b", [(0, 1, 5, 0.05), (0, 2, 5, 0.05), (0, 3, 5, 0.05)])
    assert fg.episode_figures([one, two], ["A", "B"], tmp_path, title="T") == [tmp_path / "steps_per_episode.png",
                                                                              tmp_path / "time_per_step.png"]
    steps, time = drawn["steps_per_episode.png"][0].axes[0], drawn["time_per_step.png"][0].axes[0]
    a, b = steps.get_lines()
    assert a.get_label() == "A (median, 3 seeds)" and b.get_label() == "B (median, 1 seeds)"
    assert list(a.get_xdata()) == [1, 2] and list(a.get_ydata()) == [20, 4] and list(b.get_ydata()) == [5] * 3
    band = steps.collections[0].get_paths()[0].vertices
    assert sorted(set(band[band[:, 0] == 1, 1])) == [15, 40]
    assert steps.collections[0].get_alpha() == 0.25
    assert list(steps.collections[0].get_facecolor()[0]) == pytest.approx([*matplotlib.colors.to_rgb(a.get_color()),
                                                                           0.25])
    assert list(time.get_lines()[0].get_ydata()) == pytest.approx([1, 2]) and list(
        time.get_lines()[1].get_ydata()) == pytest.approx([10] * 3)
    assert steps.get_yscale() == "log" and time.get_yscale() == "linear"
    assert steps.get_ylabel() == "steps per episode (log scale)"
    assert time.get_ylabel() == "wall time per step (ms, per seed)"
    assert steps.get_xlabel() == time.get_xlabel() == "episode"
    assert steps.get_title() == "steps per episode: median over seeds (T)"
    assert time.get_title() == "wall time per step (ms, per seed): median over seeds (T)"
    assert steps.get_legend().get_title().get_text() == "shaded: inter-quartile range"
    for ax in (steps, time):
        assert tuple(ax.figure.get_size_inches()) == (6.4, 4.0) and ax.title.get_fontsize() == 9
        legend = ax.get_legend()
        assert {t.get_fontsize() for t in [*legend.get_texts(), legend.get_title()]} == {8}
        assert {g.get_alpha() for g in ax.yaxis.get_gridlines()} == {0.3}
        assert ax.get_lines()[0].get_linewidth() == 1.2
    assert all(float(t).is_integer() for t in steps.xaxis.get_major_locator().tick_values(1, 3))
    fg.episode_figures([one], ["A"], tmp_path, logy_steps=False)
    steps = drawn["steps_per_episode.png"][0].axes[0]
    assert steps.get_yscale() == "linear" and steps.get_ylabel() == "steps per episode"
    assert steps.get_title() == "steps per episode: median over seeds"


def test_the_evaluation_figure_is_a_box_per_run_with_an_eval_csv(tmp_path, drawn):
    """Runs with eval.csv get a box each (labelled with their seeds and episodes), a log axis once
    the largest value is 5x the smallest median; none without one, or without the column."""
    def evaluated(name, steps, column="steps"):
        folder = tmp_path / name
        folder.mkdir()
        pd.DataFrame([dict(seed=s, episode=e, **{column: steps[s][e - 1]}) for s in range(len(steps))
                      for e in range(1, len(steps[0]) + 1)]).to_csv(folder / "eval.csv", index=False)
        return a_run(folder, [])
    none = a_run(tmp_path / "none", [])
    assert fg.evaluation_figure([none], ["n"], tmp_path, "steps", "steps") is None
    wide = evaluated("wide", [[17, 18, 200], [19, 20, 20]])                  # 200 >= 5 x 19.5
    old = evaluated("old", [[1, 2]], column="return")
    assert fg.evaluation_figure([wide, none, old], ["w", "n", "o"], tmp_path, "steps", "steps to goal") == \
        tmp_path / "eval_returns.png"
    ax = drawn["eval_returns.png"][0].axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["w\n(2 seeds x 3)"]
    assert ax.get_yscale() == "log" and ax.get_ylabel() == "steps to goal (log scale)"
    assert ax.yaxis.get_major_locator().integer
    assert ax.get_title() == "evaluation, exploration off\n(box: quartiles; triangle: mean)"
    assert ax.title.get_fontsize() == 9 and ax.get_xticklabels()[0].get_fontsize() == 7
    assert {g.get_alpha() for g in ax.yaxis.get_gridlines()} == {0.3}
    assert tuple(drawn["eval_returns.png"][0].get_size_inches()) == (4.0, 4.0)
    means = [ln for ln in ax.get_lines() if ln.get_marker() == "^"]
    assert [list(m.get_ydata()) for m in means] == [[pytest.approx(294 / 6)]]
    narrow = evaluated("narrow", [[17, 18, 89]])                             # 89 < 5 x 18
    ret = evaluated("ret", [[-1.0, 2.0, 3.0]], column="return")
    fg.evaluation_figure([narrow, wide], ["a", "b"], tmp_path, "steps", "steps")
    ax = drawn["eval_returns.png"][0].axes[0]
    assert ax.get_yscale() == "log"                                          # wide's 200 >= 5 x narrow's 18
    fg.evaluation_figure([narrow], ["a"], tmp_path, "steps", "steps")
    ax = drawn["eval_returns.png"][0].axes[0]
    assert ax.get_yscale() == "linear" and ax.get_ylabel() == "steps"
    fg.evaluation_figure([ret], ["r"], tmp_path, "return", "return")
    assert drawn["eval_returns.png"][0].axes[0].get_yscale() == "linear"        # a value below 0: never log
    zero = evaluated("zero", [[0.0, 2.0, 10.0]], column="return")
    fg.evaluation_figure([zero], ["z"], tmp_path, "return", "return")
    assert drawn["eval_returns.png"][0].axes[0].get_yscale() == "linear"        # nor at 0
    pos = evaluated("pos", [[1.0, 2.0, 10.0]], column="return")
    fg.evaluation_figure([pos], ["p"], tmp_path, "return", "return")
    ax = drawn["eval_returns.png"][0].axes[0]
    assert ax.get_yscale() == "log" and not ax.yaxis.get_major_locator().integer
    assert drawn["eval_returns.png"][0].get_size_inches()[0] == pytest.approx(4.0)
    fg.evaluation_figure([narrow, wide, pos, narrow], list("abcd"), tmp_path, "steps", "steps")
    fig = drawn["eval_returns.png"][0]
    assert fig.get_size_inches()[0] == pytest.approx(1.2 + 1.3 * 3)
    assert [t.get_text().split("\n")[0] for t in fig.axes[0].get_xticklabels()] == ["a", "b", "d"]   # c: no steps
