"""Rerun recordings: every rerun call (recording) and recording a trained run (record)."""
