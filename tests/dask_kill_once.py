"""Dask worker preload for tests/test_sweep.py: the first sweep task to start
kills its worker process (os._exit, as a crash or an out-of-memory kill would),
once per marker file ($WARPCOIL_TEST_KILL_MARKER), so the retry is deterministic."""

import os

from distributed import WorkerPlugin


class KillFirstTask(WorkerPlugin):
    def __init__(self, marker: str):
        self.marker = marker

    def transition(self, key, start, finish, **kwargs):
        if finish == "executing" and "warpcoil-ensemble" in str(key) and not os.path.exists(self.marker):
            with open(self.marker, "w") as file:
                file.write(str(key))
            os._exit(1)


async def dask_setup(worker):
    await worker.plugin_add(KillFirstTask(os.environ["WARPCOIL_TEST_KILL_MARKER"]), name="kill-first-task")
