"""One stand-in for pybullet, shared by the push env's and the push analysis' tests: every call
logged, each answered by a value or a function of the call."""


class Recorder:
    """pybullet's functions as a log of calls (name, args, kwargs); each returns ``answers[name]``
    (a value, or a function of the call) or None."""
    DIRECT, JOINT_FIXED, ER_TINY_RENDERER = 2, 4, 7

    def __init__(self, **answers):
        self.calls, self.answers = [], answers

    def __getattr__(self, name):
        def call(*args, **kwargs):
            self.calls.append((name, args, kwargs))
            got = self.answers.get(name)
            return got(*args, **kwargs) if callable(got) else got
        return call

    def named(self, name):
        """The (args, kwargs) of each call of ``name``, in order."""
        return [(a, k) for n, a, k in self.calls if n == name]
