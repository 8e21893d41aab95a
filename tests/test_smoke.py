import numpy as np

from apac_mj import suite


def test_every_task_loads_and_steps():
    for domain, task in suite.ALL_TASKS:
        env = suite.load(domain, task, task_kwargs={"random": 0})
        ts = env.reset()
        assert ts.first()
        ts = env.step(np.zeros(2))
        assert np.isfinite(ts.reward)
