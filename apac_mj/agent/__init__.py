"""The learner: the agent and its networks, replay, noise, integrator and arbitration rules. Knows nothing of the plant."""
