"""Speed/accuracy studies: what each knob costs and what it buys.

- `compare`: configurations rendered for the same time, errors against a
  reference (adaptive sampling, the filter, photon modes...).
- `tradeoff`: one knob at a time swept over its range (spp, depth, Russian
  roulette, NEE, photons, gather radius, cone k, photon cap, online/offline,
  progressive, adaptive, filter, precision), each setting's steady render
  time (compile time apart), samples/s and errors (RMSE, relMSE, SSIM, and
  FLIP when flip-evaluator is installed); convergence curves with the fitted
  slope of MSE against time (-1 for an unbiased setting) and, for biased
  ones, the error floor (MSE minus the image's own variance).

The reference is a high-spp path-traced EXR (photon mapping off, so it is
unbiased), given by the user or rendered once and cached
(clpt/tools/reference.py).
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import metrics
from ..constants import LUMA
from ..adaptive import AdaptiveSettings
from ..denoise import FilterSettings, OidnSettings
from ..photons import PhotonSettings
from ..render import Renderer
from ..loading import load_scene
from .reference import reference_image


@dataclass
class Setting:
    knob: str
    value: object
    renderer: dict = field(default_factory=dict)  # Renderer keywords
    render: dict = field(default_factory=dict)    # Renderer.render keywords
    biased: bool = False                          # converges to something else than the reference

    @property
    def label(self) -> str:
        return f"{self.knob}={self.value}"


class _Renderers:
    """Renderers built once per set of Renderer keywords; build and first-launch
    (device compile) times are kept apart from render times."""

    def __init__(self, scene, device, width, height):
        self.scene, self.device, self.width, self.height = scene, device, width, height
        self.cache = {}

    def get(self, kw: dict, render_kw: dict):
        key = json.dumps(kw, sort_keys=True, default=str)
        if key not in self.cache:
            t0 = time.perf_counter()
            r = Renderer(self.scene, device=self.device, **kw)
            self.cache[key] = [r, time.perf_counter() - t0, 0.0, set()]
        entry = self.cache[key]
        warm_key = json.dumps(sorted(render_kw), default=str)
        if warm_key not in entry[3]:  # the lazy device compile of each kernel used, kept out of the timings
            t0 = time.perf_counter()
            entry[0].render(1, width=self.width, height=self.height, **render_kw)
            entry[2] += time.perf_counter() - t0
            entry[3].add(warm_key)
        return entry[0], entry[1], entry[2]


def caustic_region(scene, width, height, device=None):
    """Pixels where caustic photons matter: the offline caustic buffer at
    least 5% of its peak luminance (None for scenes without casters)."""
    r = Renderer(scene, device=device)
    if not r.features.photons:
        return None
    res = r.render(16, width=width, height=height, photons=PhotonSettings(mode="offline"))
    lum = res.caustic_image @ LUMA
    return lum >= 0.05 * max(float(lum.max()), 1e-12)


def _measure(renderers, setting: Setting, ref, spp=None, seconds=None, seed=1, region=None) -> dict:
    kw = dict(setting.render)
    r, build, first = renderers.get(setting.renderer, kw)
    res = r.render(spp if spp is not None else 1 << 24, width=renderers.width, height=renderers.height, seed=seed,
                   time_limit=seconds, **kw)
    img = res.filtered if res.filtered is not None else res.image
    var_mean = float((res.lum_var / np.maximum(res.sample_count, 1)).mean())
    row = {"knob": setting.knob, "value": str(setting.value), "biased": setting.biased,
           "seconds": res.stats.render_seconds, "spp": float(res.sample_count.mean()),
           "msamples_per_s": res.samples / max(res.stats.render_seconds, 1e-9) / 1e6,
           "build_seconds": build, "first_launch_seconds": first, "variance_of_mean": var_mean,
           "mse": float(((img.astype(np.float64) - ref) ** 2).mean()), "nonfinite": res.stats.nonfinite}
    # What the reference's own noise adds to the MSE is taken out.
    row["mse_excess"] = max(row["mse"] - float(getattr(ref, "noise", 0.0)), 1e-300)
    row.update(metrics.all_metrics(img, ref))
    if region is not None and region.any():
        row["rmse_caustic"] = metrics.rmse(img[region], ref[region])
    return row


def compare(scene, configs: list[Setting], *, ref, seconds: float, width: int, height: int, device=None,
            seed=1) -> list[dict]:
    """Each configuration rendered for `seconds`; errors against ref."""
    renderers = _Renderers(scene, device, width, height)
    return [_measure(renderers, c, ref, seconds=seconds, seed=seed) for c in configs]


# compare's adaptive renders: a noise threshold no render of seconds reaches, so that adaptive
# sampling spends the whole time, as uniform sampling does (at the default 0.02 it stops once
# every pixel is below it: on the caustics box after about half of 8 seconds).
EQUAL_TIME_ADAPTIVE = AdaptiveSettings(threshold=1e-3)


def _has_oidn() -> bool:
    try:
        import pyoidn  # noqa: F401
    except ImportError:
        return False
    return True


def denoise_settings(prefix: str = "method") -> list[Setting]:
    """OIDN alone and with adaptive sampling (when pyoidn is installed)."""
    if not _has_oidn():
        return []
    aux = {"aux": True}
    return [Setting(prefix, "oidn", renderer=aux, render={"filter": OidnSettings()}, biased=True),
            Setting(prefix, "adaptive-error+oidn", renderer=aux,
                    render={"adaptive": EQUAL_TIME_ADAPTIVE, "filter": OidnSettings()}, biased=True)]


def standard_comparison() -> list[Setting]:
    """Uniform sampling, the two adaptive schemes, the cone filter and OIDN, and
    each denoiser with adaptive sampling."""
    aux = {"aux": True}
    return [
        Setting("method", "uniform"),
        Setting("method", "adaptive-error", render={"adaptive": EQUAL_TIME_ADAPTIVE}),
        Setting("method", "adaptive-paper", render={"adaptive": AdaptiveSettings(scheme="paper")}, biased=True),
        Setting("method", "filter", renderer=aux, render={"filter": FilterSettings()}, biased=True),
        Setting("method", "adaptive-error+filter", renderer=aux,
                render={"adaptive": EQUAL_TIME_ADAPTIVE, "filter": FilterSettings()}, biased=True),
    ] + denoise_settings()


def knob_settings(has_photons: bool, max_depth: int = 8) -> list[Setting]:
    """Every knob's sweep; defaults elsewhere."""
    s = [Setting("max_depth", d, render={"max_depth": d}, biased=d < max_depth) for d in (0, 1, 2, 3, 4, 6, 8, 16)]
    s += [Setting("rr_depth", d, render={"rr_depth": d}) for d in (0, 1, 2, 4, 8, 1000)]
    s += [Setting("nee", v, renderer={"nee": v}) for v in (True, False)]
    s += [Setting("precision", p, renderer={"precision": p}) for p in ("float", "double")]
    s += [Setting("adaptive", t, render={"adaptive": AdaptiveSettings(threshold=t)}) for t in (0.1, 0.05, 0.02)]
    s += [Setting("adaptive", "paper", render={"adaptive": AdaptiveSettings(scheme="paper")}, biased=True)]
    s += [Setting("filter", w, renderer={"aux": True}, render={"filter": FilterSettings(width=w)}, biased=w > 0)
          for w in (0, 1, 2, 3)]
    if _has_oidn():
        s += [Setting("denoise", f"oidn-{m}", renderer={"aux": True}, render={"filter": OidnSettings(aux=m)},
                      biased=True) for m in ("clean", "noisy", "none")]
    if has_photons:
        def ps(**kw):
            return {"photons": PhotonSettings(**{"pilot": False, **kw})}
        s += [Setting("photons", "off", renderer={"photons": False})]
        s += [Setting("photons", f"{k}/sample", render=ps(photons_per_sample=k), biased=True)
              for k in (0.05, 0.25, 1.0)]
        s += [Setting("photons", "pilot", render={"photons": PhotonSettings()}, biased=True)]
        s += [Setting("radius", r, render=ps(radius=r), biased=True) for r in (0.002, 0.004, 0.008, 0.016)]
        s += [Setting("cone_k", k, render=ps(cone_k=k), biased=True) for k in (1.0, 1.1, 2.0)]
        s += [Setting("merge_vertices", m, render=ps(merge_vertices=m), biased=True) for m in (1, 2, 1 << 20)]
        s += [Setting("merge_probability", m, render=ps(merge_probability=m), biased=True) for m in (0.25, 0.5, 1.0)]
        s += [Setting("photon_mode", m, render=ps(mode=m), biased=True) for m in ("merge", "online", "offline")]
        s += [Setting("max_photons", m, render=ps(mode="online", max_photons=m), biased=True) for m in (0, 16)]
        s += [Setting("progressive", a, render=ps(alpha=a), biased=True) for a in (0.5, 0.7, 0.9)]
        s += [Setting("progressive", "fixed map", render=ps(progressive=False), biased=True)]
    return s


def convergence_settings(has_photons: bool) -> list[Setting]:
    """Settings whose error is followed as the samples grow."""
    c = [Setting("converge", "path tracing", renderer={"photons": False}),
         Setting("converge", "filter", renderer={"aux": True, "photons": False},
                 render={"filter": FilterSettings()}, biased=True),
         Setting("converge", "max_depth=2", renderer={"photons": False}, render={"max_depth": 2}, biased=True)]
    # Denoising with and without adaptive sampling: which combination buys the
    # most accuracy per second (denoise.png).
    aux = {"aux": True}
    c += [Setting("converge", "adaptive", render={"adaptive": AdaptiveSettings()}),
          Setting("converge", "cone", renderer=aux, render={"filter": FilterSettings()}, biased=True),
          Setting("converge", "adaptive+cone", renderer=aux,
                  render={"adaptive": AdaptiveSettings(), "filter": FilterSettings()}, biased=True)]
    if _has_oidn():
        c += [Setting("converge", "oidn", renderer=aux, render={"filter": OidnSettings()}, biased=True),
              Setting("converge", "adaptive+oidn", renderer=aux,
                      render={"adaptive": AdaptiveSettings(), "filter": OidnSettings()}, biased=True)]
    if has_photons:
        c += [Setting("converge", "merging (progressive)", render={"photons": PhotonSettings(pilot=False)}),
              Setting("converge", "merging, fixed map", biased=True,
                      render={"photons": PhotonSettings(pilot=False, progressive=False)}),
              Setting("converge", "owned map, online", biased=True, render={"photons": PhotonSettings(mode="online")})]
    return c


# With the scene's default photon mapping (the "merging (progressive)" curve is
# their baseline where the scene has caustic casters; "path tracing" has photons off).
DENOISE_CURVES = ("path tracing", "merging (progressive)", "adaptive", "cone", "adaptive+cone", "oidn",
                  "adaptive+oidn")
PHOTON_KNOBS = ("photons", "radius", "cone_k", "max_photons", "photon_mode", "progressive", "merge_vertices",
                "merge_probability")


def fit_slope(x, y) -> float:
    """Least-squares slope of log y against log x."""
    lx, ly = np.log(np.asarray(x, float)), np.log(np.maximum(np.asarray(y, float), 1e-300))
    return float(np.polyfit(lx, ly, 1)[0])


def tradeoff(scene_name, *, out_dir, width=64, height=64, spp=64, ref_spp=16384, reference=None, device=None,
             spp_steps=(1, 4, 16, 64, 256), log=print) -> dict:
    """The whole sweep for one scene; writes rows.csv, rows.json, summary.json and plots to out_dir."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scene = load_scene(scene_name)
    ref_path = Path(reference) if reference else out / f"reference_{width}x{height}_{ref_spp}spp.exr"
    t0 = time.perf_counter()
    ref = reference_image(scene, width, height, ref_spp, ref_path, device)
    log(f"reference: {ref_path} ({time.perf_counter() - t0:.1f} s)")
    region = caustic_region(scene, width, height, device)
    has_photons = region is not None
    renderers = _Renderers(scene, device, width, height)
    rows = []
    for s in knob_settings(has_photons):
        row = _measure(renderers, s, ref, spp=spp, region=region)
        rows.append(row)
        log(f"  {s.label:32s} {row['seconds']:7.3f} s  relMSE {row['relmse']:.4g}  SSIM {row['ssim']:.3f}"
            + (f"  RMSE caustic {row['rmse_caustic']:.4g}" if "rmse_caustic" in row else ""))
    curves = {}
    for s in convergence_settings(has_photons):
        pts = []
        for n in spp_steps:
            row = _measure(renderers, s, ref, spp=n, region=region)
            row["knob"], row["value"] = "converge:" + str(s.value), str(n)
            rows.append(row)
            pts.append(row)
        secs = [p["seconds"] for p in pts]
        mse = [p["mse_excess"] for p in pts]
        # MSE = bias^2 + variance: at the most samples, what the variance does not explain.
        floor = max(0.0, pts[-1]["mse_excess"] - pts[-1]["variance_of_mean"])
        curves[str(s.value)] = {"seconds": secs, "mse": mse, "spp": list(spp_steps), "biased": s.biased,
                                "relmse": [p["relmse"] for p in pts],
                                "slope_mse_vs_time": fit_slope(secs, mse),
                                "slope_mse_vs_spp": fit_slope(spp_steps, mse),
                                "bias_floor_mse": floor}
        c = curves[str(s.value)]
        log(f"  converge {s.value!s:22s} MSE ~ spp^{c['slope_mse_vs_spp']:.2f}, time^{c['slope_mse_vs_time']:.2f}"
            + (f", floor ~{floor:.3g}" if s.biased else ""))
    summary = {"scene": scene_name, "resolution": f"{width}x{height}", "spp": spp, "reference_spp": ref_spp,
               "curves": curves, "best_per_knob": _best_per_knob(rows), "pareto": _pareto(rows),
               "caustic_rows": [r for r in rows if "rmse_caustic" in r and r["knob"] in PHOTON_KNOBS]}
    with open(out / "rows.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=sorted({k for r in rows for k in r}))
        w.writeheader()
        w.writerows(rows)
    (out / "rows.json").write_text(json.dumps(rows, indent=1, default=str))
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    _plots(out, rows, curves, scene_name, log)
    return summary


def _pareto(rows) -> list[str]:
    """Settings (not convergence points) that no other is both faster and more accurate than."""
    pts = [r for r in rows if not r["knob"].startswith("converge")]
    front = []
    for r in pts:
        if not any(o["seconds"] <= r["seconds"] and o["relmse"] <= r["relmse"] and o is not r and
                   (o["seconds"] < r["seconds"] or o["relmse"] < r["relmse"]) for o in pts):
            front.append(f"{r['knob']}={r['value']}")
    return front


def _best_per_knob(rows) -> dict:
    """Per knob: the value with the least relMSE x time (accuracy per second)."""
    best = {}
    for r in rows:
        if r["knob"].startswith("converge"):
            continue
        score = r["relmse"] * r["seconds"]
        if r["knob"] not in best or score < best[r["knob"]][1]:
            best[r["knob"]] = (r["value"], score)
    return {k: {"value": v, "relmse_x_seconds": s} for k, (v, s) in best.items()}


def _plots(out: Path, rows, curves, title, log):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log("  (no plots: pip install matplotlib)")
        return
    knobs = sorted({r["knob"] for r in rows if not r["knob"].startswith("converge")})
    pareto = set(_pareto(rows))
    # Small multiples: one panel per knob on shared axes, with the plain
    # path tracer's point (the default max_depth row, photons off when the
    # scene has them) in every panel to read each trade against.
    base = next((r for r in rows if r["knob"] == "photons" and str(r["value"]) == "off"), None) or \
        next((r for r in rows if r["knob"] == "max_depth" and str(r["value"]) == "8"), None)
    cols = 4
    nrows = -(-len(knobs) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.2 * cols, 2.6 * nrows), sharex=True, sharey=True,
                             squeeze=False)
    for ax, k in zip(axes.flat, knobs):
        pts = [r for r in rows if r["knob"] == k]
        ax.loglog([p["seconds"] for p in pts], [p["relmse"] for p in pts], "o-", color="C0", ms=4)
        for p in pts:
            if f"{p['knob']}={p['value']}" in pareto:
                ax.plot(p["seconds"], p["relmse"], "k*", ms=11, mfc="none")
            ax.annotate(str(p["value"]), (p["seconds"], p["relmse"]), fontsize=6, alpha=0.8,
                        xytext=(3, 3), textcoords="offset points")
        if base is not None:
            ax.plot(base["seconds"], base["relmse"], "s", color="C3", ms=6, label="path tracing")
        ax.set_title(k, fontsize=9)
        ax.grid(True, which="both", alpha=0.2)
    for ax in list(axes.flat)[len(knobs):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("relMSE", fontsize=8)
    fig.suptitle(f"{title}: relMSE against time, one knob at a time (stars: Pareto front; "
                 f"red square: path tracing)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    fig.savefig(out / "knobs.png", dpi=110)
    plt.close(fig)
    # MSE less the reference's noise
    _curve_plot(plt, out / "convergence.png", [(f"{name}: slope {c['slope_mse_vs_time']:.2f}"
                                                + (" (biased)" if c["biased"] else ""), c["seconds"], c["mse"], None)
                                               for name, c in curves.items()],
                "render time (s)", "MSE", f"{title}: convergence")
    den = {k: c for k, c in curves.items() if k in DENOISE_CURVES and "relmse" in c}
    if den:
        _curve_plot(plt, out / "denoise.png", [(k, c["seconds"], c["relmse"], c["spp"]) for k, c in den.items()],
                    "render + denoise time (s)", "relMSE", f"{title}: denoising and adaptive sampling (labels: spp)")


def _curve_plot(plt, path, series, xlabel, ylabel, title):
    """Log-log curves (label, x, y, point labels or None) in one plot."""
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for i, (label, xs, ys, tags) in enumerate(series):
        ax.loglog(xs, ys, "o-", color=f"C{i % 10}", label=label)
        for x, y, t in zip(xs, ys, tags or ()):
            ax.annotate(str(t), (x, y), fontsize=6, alpha=0.7)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _denoise_lines(name, summary) -> list[str]:
    """The denoising curves: relMSE and time at each spp, and the combination
    with the least relMSE x time."""
    den = {k: c for k, c in summary["curves"].items() if k in DENOISE_CURVES and "relmse" in c}
    if not den:
        return []
    spps = next(iter(den.values()))["spp"]
    lines = [f"![denoising]({name}/denoise.png)", "",
             "| relMSE (seconds) | " + " | ".join(f"{n} spp" for n in spps) + " |",
             "|---|" + "---|" * len(spps)]
    best = None
    for k, c in den.items():
        lines.append(f"| {k} | " + " | ".join(f"{e:.3g} ({t:.2f} s)" for e, t in zip(c["relmse"], c["seconds"]))
                     + " |")
        for e, t, n in zip(c["relmse"], c["seconds"], c["spp"]):
            if best is None or e * t < best[0]:
                best = (e * t, k, n)
    lines += ["", f"Most accuracy per second (least relMSE x time): {best[1]} at {best[2]} spp.", ""]
    return lines


def format_table(rows, keys=("knob", "value", "seconds", "spp", "msamples_per_s", "rmse", "relmse", "ssim", "flip")):
    keys = [k for k in keys if any(k in r for r in rows)]
    lines = ["  ".join(f"{k:>14s}" for k in keys)]
    for r in rows:
        cells = []
        for k in keys:
            v = r.get(k, "")
            cells.append(f"{v:14.4g}" if isinstance(v, float) and not math.isnan(v) else f"{str(v):>14s}")
        lines.append("  ".join(cells))
    return "\n".join(lines)


def write_summary(out_dir, summaries: list[dict], compare_rows: dict | None = None, command: str = ""):
    """docs-style markdown of the sweeps: convergence slopes, error floors,
    the best value of each knob per second, the Pareto front, and links to plots."""
    out = Path(out_dir)
    lines = ["# Speed and accuracy, measured", "",
             f"Regenerate with `{command}`." if command else "", "",
             "Each scene is rendered at its resolution below with one knob changed at a time (others at their "
             "defaults, 64 spp), against a path-traced reference of many samples (photon mapping off, so it is "
             "unbiased). Times are steady-state render times (kernel builds and the first launch apart).", ""]
    for s in summaries:
        name = s["scene"]
        lines += [f"## {name} ({s['resolution']}, reference {s['reference_spp']} spp)", "",
                  f"![knobs]({name}/knobs.png) ![convergence]({name}/convergence.png)", "",
                  *_denoise_lines(name, s),
                  "| convergence of | MSE ~ spp^ | MSE ~ time^ | error floor (MSE) |", "|---|---|---|---|"]
        for cname, c in s["curves"].items():
            floor = f"{c['bias_floor_mse']:.3g}" if c["biased"] else "- (unbiased)"
            lines.append(f"| {cname} | {c['slope_mse_vs_spp']:.2f} | {c['slope_mse_vs_time']:.2f} | {floor} |")
        if s.get("caustic_rows"):
            lines += ["", "Photon knobs, error in the caustic region (where photons matter):", "",
                      "| setting | seconds | RMSE caustic | relMSE image |", "|---|---|---|---|"]
            for r in s["caustic_rows"]:
                lines.append(f"| {r['knob']}={r['value']} | {r['seconds']:.3f} | {r['rmse_caustic']:.4g} | "
                             f"{r['relmse']:.4g} |")
        lines += ["", "| knob | most accuracy per second (least relMSE x time) |", "|---|---|"]
        for k, v in sorted(s["best_per_knob"].items()):
            lines.append(f"| {k} | {v['value']} ({v['relmse_x_seconds']:.3g}) |")
        lines += ["", "Pareto front (no setting is both faster and more accurate): "
                  + ", ".join(f"`{p}`" for p in s["pareto"]), ""]
    if compare_rows:
        lines += ["## Equal render time: uniform, adaptive, filtered", ""]
        for name, rows in compare_rows.items():
            lines += [f"### {name}", "", "| method | spp (mean) | relMSE | SSIM | FLIP |", "|---|---|---|---|---|"]
            for r in rows:
                lines.append(f"| {r['value']} | {r['spp']:.1f} | {r['relmse']:.4g} | {r['ssim']:.3f} | "
                             f"{r.get('flip', float('nan')):.4f} |")
            lines.append("")
    (out / "README.md").write_text("\n".join(lines) + "\n")
