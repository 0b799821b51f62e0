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


def test_a_replay_starts_each_job_when_a_worker_frees_and_asks_the_guide_with_the_new_costs():
    """Three jobs on 2 workers, the run's estimates a 10, c 6, b 5 (so a and c start at 0 s, b when
    c ends at 6 s); a ends at 12 s, b at 14 s. With the same costs, by hand (sweep.seconds_left):
    at 6 s, rate 6/6 = 1, a has max(10 - 6, 0.25 * 6) = 4 s left, b 5 on the free worker: 5;
    at 12 s, rate (6 + 12) / 16, b has run 6 s of 5 * 18/16 = 5.625: the floor 0.25 * 6 = 1.5;
    at 14 s nothing is left to guess. With every cost 1 the rate is 6 s a unit: at 6 s a has
    max(6 - 6, 1.5) = 1.5 left and b 6 ahead: 6."""
    from trl_dgpq.collectors.sweep import Job
    jobs = [Job(x, 0, [0], "", {}) for x in "abc"]
    name = {j.experiment: j.name for j in jobs}
    recorded = {name["a"]: 10.0, name["b"]: 5.0, name["c"]: 6.0}
    stamped = [(0.0, "reproduce (quick) -> x: 3 experiments, 2 workers"),
               (6.0, f"[1/3 jobs done, 0 not finished, 2 to go (2 running); 0.1 min] {name['c']}: finished"),
               (12.0, f"[2/3 jobs done, 0 not finished, 1 to go (1 running); 0.2 min] {name['a']}: finished"),
               (14.0, f"[3/3 jobs done, 0 not finished, 0 to go; 0.2 min] {name['b']}: finished"),
               (20.0, "wrote x/REPORT.md")]
    assert bench_quick.ended(stamped) == [(6.0, name["c"]), (12.0, name["a"]), (14.0, name["b"])]
    by_cost = bench_quick.replay(stamped, jobs, recorded, 2, lambda j: recorded[j.name])
    assert by_cost == [(6.0, 5.0), (12.0, 1.5), (14.0, None)]
    assert bench_quick.replay(stamped, jobs, recorded, 2, lambda j: 1.0)[0] == (6.0, 6.0)
    # one worker: a alone first, then c, then b; at a's end (6 s here) c and b are still to come
    one = [stamped[0], (6.0, stamped[2][1]), (12.0, stamped[1][1]), (14.0, stamped[3][1])]
    assert bench_quick.replay(one, jobs, recorded, 1, lambda j: recorded[j.name])[0] == (6.0, 6.6)
