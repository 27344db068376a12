"""The render engine: a render as work items over raw per-pixel sums.

    job.py         RenderJob (scene + settings, hashable, picklable), WorkItem, photon_plan
    schedule.py    which item comes next; what is done; its position as plain data
    accum.py       Accumulator: raw float64 sums; add, merge, bytes, device layouts, finish
    launch.py      the kernels' launch records (numpy dtypes) and argument names
    passes.py      TracePass, PhotonPass, FilterPass: each pass's kernels, buffers and timings
    device.py      DeviceWorker: one OpenCL device's passes running items into sums it keeps
    runresult.py   RunResult: what running an item reports
    executors.py   LocalExecutor (worker threads), DaskExecutor (tasks returning sums)
    driver.py      the loop: balancing, failures, checkpoints, updates, signals; run_item
    checkpoint.py  atomic checkpoint files and their checks
"""
