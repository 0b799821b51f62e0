"""bench.py quick's reading of a reproduction's output: each progress line's guess of the time
left against the truth (the sweep's last line minus the line's own time)."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
import bench_quick  # noqa: E402


def test_each_guess_is_judged_against_the_time_the_sweep_then_took():
    """Lines at 10, 40, 70 and 100 s; the last ends the sweep at 100 s. Guesses 1.5 min (truth 90 s:
    on it), 0.6 min (60: 40 % low), none (a line before any job ended), and 2 h on a line 30 s
    before the end (way off); a 4 s truth guessed at 9 s is within the line's 6 s resolution."""
    stamped = [(0.0, "reproduce (quick) -> x: 3 experiments, 2 workers"),
               (10.0, "[1/5 jobs done, 0 not finished, 4 to go (2 running); 0.2 min, ~1.5 min left at this rate] a"),
               (40.0, "[2/5 jobs done, 0 not finished, 3 to go (2 running); 0.7 min, ~0.6 min left at this rate] b"),
               (55.0, "[3/5 jobs done, 1 not finished, 2 to go (2 running); 0.9 min] c: failed"),
               (70.0, "[4/5 jobs done, 0 not finished, 1 to go (1 running); 1.2 min, ~2.0 h left at this rate] d"),
               (96.0, "[4/5 jobs done, 0 not finished, 1 to go (1 running); 1.6 min, ~0.15 min left at this rate] e"),
               (100.0, "[5/5 jobs done, 0 not finished, 0 to go; 1.7 min] f: finished"),
               (130.0, "wrote x/REPORT.md")]
    points = bench_quick.guesses(stamped)
    assert points == [(10.0, 90.0), (40.0, 36.0), (55.0, None), (70.0, 7200.0), (96.0, 9.0), (100.0, None)]
    got = bench_quick.judged(points)
    assert [(v["at_s"], v["truth_s"], v["within"]) for v in got] == [
        (10.0, 90.0, True), (40.0, 60.0, False), (70.0, 30.0, False), (96.0, 4.0, True)]
    assert [v["within"] for v in bench_quick.judged(points, tolerance=0.5)] == [True, True, False, True]


def test_the_summary_says_so_where_no_job_ran_or_none_has_an_estimate():
    """No progress line (the run failed before a job ended): one line, not a crash on the empty list;
    jobs with no estimate: the ratio is left out rather than divided by zero."""
    assert bench_quick.summary(90.0, [], [], []) == ["wall 1.5 min; no progress line (no job ran)"]
    lines = bench_quick.summary(120.0, [(60.0, None)], [], [dict(estimate_s=0.0, steps_estimate_s=0.0, cpu_in_episodes_s=30.0)])
    assert lines[1] == "wall 2.0 min: the sweep 1.0, the report after it 1.0"
    assert lines[2] == "time-left guide within 25 % (or 6 s) of the truth at 0 of its 0 reports"
    assert lines[3] == ("CPU time in the episodes 0.50 min of one core against the estimate's 0.00 (no estimate; "
                        "the estimate counts each job's start, the rows do not)")
    ok = bench_quick.summary(120.0, [(60.0, None)], [dict(within=True), dict(within=False)],
                             [dict(estimate_s=40.0, steps_estimate_s=39.0, cpu_in_episodes_s=30.0),
                              dict(estimate_s=20.0, steps_estimate_s=3.0, cpu_in_episodes_s=33.0)])
    assert ok[2].endswith("at 1 of its 2 reports")
    assert "1.05 min of one core against the estimate's 1.00 (x1.05; x1.50 its steps alone, 0.70;" in ok[3]
