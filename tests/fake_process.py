"""One stand-in for multiprocessing's worker processes, shared by the sweep's and tune's tests:
nothing runs, each start and join is logged, and a test's hooks run inside them (where a signal
may arrive)."""
import signal


class FakeProcess:
    """A worker that ends with ``code`` when joined (-SIGTERM once terminated); pids from 4242 in
    the order made; ``on_start(proc)``/``on_join(proc)`` run inside start() and join()."""
    made, log = [], []

    def __init__(self, target=None, args=(), name="", code=0, on_start=None, on_join=None):
        self.target, self.args, self.name, self.code = target, args, name, code
        self.on_start, self.on_join = on_start, on_join
        self.sentinel, self.exitcode, self.pid, self.terminated = object(), None, None, False
        FakeProcess.made.append(self)

    def start(self):
        self.pid = 4242 + FakeProcess.made.index(self)
        FakeProcess.log.append(("start", self.pid))
        if self.on_start:
            self.on_start(self)

    def join(self):
        FakeProcess.log.append(("join", self.pid))
        if self.on_join:
            self.on_join(self)
        self.exitcode = -signal.SIGTERM if self.terminated else self.code

    def is_alive(self):
        return self.exitcode is None

    def terminate(self):
        self.terminated = True


def fake_context(monkeypatch, mp, method=None, codes=(), **hooks):
    """``mp.get_context(method)`` (any method when None) gives a context whose k-th process ends
    with ``codes[k]`` (0 past them); the context records what its forkserver would preload."""
    FakeProcess.made, FakeProcess.log = [], []
    codes = list(codes)

    class Context:
        preload = None

        def Process(self, target=None, args=(), name=""):
            return FakeProcess(target, args, name, codes.pop(0) if codes else 0, **hooks)

        def set_forkserver_preload(self, modules):
            Context.preload = list(modules)
    monkeypatch.setattr(mp, "get_context", lambda m: Context() if method is None or m == method else None)
    return Context
