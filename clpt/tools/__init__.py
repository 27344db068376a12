"""The lab: benchmarks, speed/accuracy studies and image metrics, the tools
behind `clpt bench*`, `clpt compare` and `clpt tradeoff`.

- bench: throughput, kernel times, memory and builds (`clpt bench`,
  `bench-builds`, `bench-photons`, `bench-bvh`)
- bench_denoise: the denoisers against references (`clpt bench-denoise`)
- studies: equal-time comparisons and knob sweeps (`clpt compare`,
  `clpt tradeoff`)
- metrics: image errors against a reference (RMSE, relMSE, SSIM, FLIP)
- reference: the high-spp path-traced reference they all measure against

They use the library; the library never imports them (`import clpt` and
`clpt render` load none of this package), and only their subcommands do.
"""
