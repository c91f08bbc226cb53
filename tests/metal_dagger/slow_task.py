"""A corridor task whose expert is slow, so a pairs run can be killed while seeds are in flight."""

import time

from toy_task import CorridorTask


class SlowCorridorTask(CorridorTask):
    def expert(self, env):
        time.sleep(0.004)
        return super().expert(env)
