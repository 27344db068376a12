"""Command-line options generated from the settings dataclasses.

Each option of `clpt render` that sets a field of PhotonSettings,
AdaptiveSettings, FilterSettings or OidnSettings is one `Option` here: its
flag, the field, and a help text. The type comes from the field's default,
and "(default ...)" is taken from the dataclass, so every default is written
once, in the dataclass. Help texts may name other fields' defaults as
{field}. A switch (`value=...`) sets its field to that value.

An option is "given" when its value is not None: argparse leaves every
generated option at None unless it is on the command line, and
`settings_kwargs` passes only the given ones to the dataclass.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields

from .adaptive import AdaptiveSettings
from .denoise import FilterSettings, OidnSettings
from .photons import PhotonSettings

_TAKES_VALUE = object()


@dataclass(frozen=True)
class Option:
    flag: str                    # "--radius"
    field: str                   # the settings field it sets
    help: str
    value: object = _TAKES_VALUE  # a switch: sets the field to this value
    choices: tuple | None = None
    metavar: str | None = None
    show_default: bool = True

    @property
    def dest(self) -> str:
        return self.flag.lstrip("-").replace("-", "_")

    def is_switch(self) -> bool:
        return self.value is not _TAKES_VALUE


def field_default(cls, name: str):
    for f in fields(cls):
        if f.name == name:
            if f.default is not MISSING:
                return f.default
            return f.default_factory() if f.default_factory is not MISSING else None
    raise KeyError(f"{cls.__name__} has no field {name!r}")


def _defaults(cls) -> dict:
    return {f.name: field_default(cls, f.name) for f in fields(cls)}


def _value_type(cls, name: str):
    d = field_default(cls, name)
    if d is not None and not isinstance(d, bool):
        return type(d)
    ann = next(f.type for f in fields(cls) if f.name == name)
    text = ann if isinstance(ann, str) else getattr(ann, "__name__", str(ann))
    for t in (int, float, str):
        if text.split("|")[0].strip() == t.__name__:
            return t
    raise TypeError(f"{cls.__name__}.{name}: cannot tell the option's type from {text!r}")


def _format_default(v) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, int) and not isinstance(v, bool) and v >= 1 << 16 and (v & (v - 1)) == 0:
        return f"2^{v.bit_length() - 1}"
    return str(v)


PHOTON_OPTIONS = (
    Option("--photons", "count", "photons per photon map (default: {photons_per_sample} per camera sample of a "
                                 "progressive iteration, 10^6 for a fixed map); 0 turns photon mapping off",
           metavar="N", show_default=False),
    Option("--radius", "radius", "gather radius, a fraction of the scene size, or absolute with --radius-absolute"),
    Option("--radius-absolute", "radius_absolute", "the gather radius is a length, not a fraction of the "
                                                   "scene size", value=True),
    Option("--cone-k", "cone_k", "cone filter constant k >= 1"),
    Option("--max-photons", "max_photons", "use at most this many photons per gather (the paper's cap; 0: no cap)"),
    Option("--photon-budget", "budget", "photons visited per row of cells before unbiased subsampling"),
    Option("--photon-mode", "mode", "merge: photon merging at every non-delta vertex weighted against path "
                                    "tracing by MIS; online: the photon map owns the caustic paths at the first "
                                    "diffuse vertex; offline: that, gathered in a pre-pass into a caustic buffer",
           choices=("merge", "online", "offline")),
    Option("--merge-vertices", "merge_vertices", "merge at the first N non-delta vertices of a camera path"),
    Option("--merge-probability", "merge_probability", "merge at a vertex with this probability (Russian "
                                                       "roulette on the merge)"),
    Option("--no-photon-pilot", "pilot", "always use the photon map (no pilot deciding whether it pays)",
           value=False),
    Option("--pilot-trial", "pilot_trial", "the pilot also times a small trial of each technique and keeps "
                                          "merging only where its relMSE per second is the lower", value=True),
    Option("--offline-spp", "offline_spp", "samples per pixel of the offline pre-pass"),
    Option("--aim", "aim", "share photons among casters by solid angle or equally (the paper)",
           choices=("solid_angle", "equal")),
    Option("--progressive", "progressive", "a fresh photon map every --spp-per-map samples, with a shrinking "
                                           "radius (the default with --photon-mode merge)", value=True),
    Option("--alpha", "alpha", "progressive radius reduction"),
    Option("--spp-per-map", "spp_per_map", "samples per pixel per photon map (progressive)"),
)

ADAPTIVE_OPTIONS = (
    Option("--min-spp", "min_spp", "uniform samples before adapting"),
    Option("--noise-threshold", "threshold", "error scheme: stop a pixel at this relative error"),
    Option("--adaptive-pass-spp", "pass_spp", "most samples a pixel gets per pass, or its count so far if more"),
    Option("--no-depth-reduction", "reduce_depth", "paper scheme: keep full depth for calm pixels (no bias)",
           value=False),
    Option("--paper-stop", "paper_mode", "paper scheme: stop calm pixels instead of slowing them", value="stop"),
)

CONE_FILTER_OPTIONS = (
    Option("--filter-width", "width", "cone radius in pixels per pass (at most 16)"),
    Option("--filter-iterations", "iterations", "a-trous passes (passes wider than the image are skipped)"),
)

DENOISER_OPTIONS = (  # both denoisers'
    Option("--filter-interval", "interval", "also write the filtered image so far every N passes (a progressive "
                                            "preview; 0: only the final image)"),
)

OIDN_OPTIONS = (
    Option("--oidn-aux", "aux", "OIDN's guides: albedo and normal prefiltered by OIDN (clean), as rendered "
                                "(noisy), or none (colour only)", choices=("clean", "noisy", "none")),
)

GROUPS = ((PhotonSettings, PHOTON_OPTIONS), (AdaptiveSettings, ADAPTIVE_OPTIONS),
          (FilterSettings, CONE_FILTER_OPTIONS + DENOISER_OPTIONS), (OidnSettings, OIDN_OPTIONS + DENOISER_OPTIONS))


def help_text(cls, opt: Option) -> str:
    text = opt.help.format(**{k: _format_default(v) for k, v in _defaults(cls).items()})
    if opt.show_default and not opt.is_switch():
        d = field_default(cls, opt.field)
        if d is not None:
            text += f" (default {_format_default(d)})"
    return text


def add_options(group, cls, options):
    """Add `options` (fields of the settings class cls) to an argparse group."""
    for opt in options:
        if opt.is_switch():
            group.add_argument(opt.flag, dest=opt.dest, action="store_const", const=opt.value, default=None,
                               help=help_text(cls, opt))
        else:
            group.add_argument(opt.flag, dest=opt.dest, type=_value_type(cls, opt.field), default=None,
                               choices=opt.choices, metavar=opt.metavar, help=help_text(cls, opt))


def given(a, options) -> list[Option]:
    """The options of `options` given on the command line (parsed as a)."""
    return [o for o in options if getattr(a, o.dest, None) is not None]


def settings_kwargs(a, options) -> dict:
    """The settings fields that the given options set."""
    return {o.field: getattr(a, o.dest) for o in given(a, options)}
