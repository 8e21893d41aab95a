"""The experiment grid: presets, cells, executors (local, Ray) and the results they leave."""
