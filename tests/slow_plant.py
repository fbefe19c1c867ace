"""A test double for tests/test_build.py: the linear example plant, slowed down and counting its
trims (module-level counter), importable by a build running in another process."""
import time

from models.linear import LinearPlant

CALLS = {"trim": 0}


class SlowPlant(LinearPlant):
    def __init__(self, delay=0.05):
        super().__init__()
        self.delay = delay

    def parameters(self):
        return {"delay": self.delay}

    def trim(self, p, h, env, guess=None):
        CALLS["trim"] += 1
        time.sleep(self.delay)
        return super().trim(p, h, env, guess)
