"""The render engine: a render as work items over raw per-pixel sums.

    job.py         RenderJob (scene + settings, hashable, picklable), WorkItem, photon_plan
    schedule.py    which item comes next; what is done; its position as plain data
    accum.py       Accumulator: raw float64 sums; add, merge, bytes, device layouts, finish
    launch.py      trace_paths' arguments from one launch record (numpy dtype)
    device.py      DeviceWorker: one OpenCL device running items into sums it keeps
    executors.py   LocalExecutor (worker threads), DaskExecutor (tasks returning sums)
    driver.py      the loop: balancing, failures, checkpoints, updates, signals
    checkpoint.py  atomic checkpoint files and their checks
"""
