"""The render engine: jobs, schedules, accumulators, executors, checkpoints and the driver loop."""
