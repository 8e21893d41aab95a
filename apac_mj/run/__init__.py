"""One run: the episode loop, the trainer, frozen evaluation and checkpoints."""
